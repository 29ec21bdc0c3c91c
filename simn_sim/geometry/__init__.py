"""Pure geometry: SE(3) helpers, camera models, 2-D free space and exact shortest paths."""
