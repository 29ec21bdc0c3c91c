"""Regenerate the fixed reference office ``envs/office_reference.json`` (layout_seed 0).

The reference office is kept as data so that ``SimnOffice-v0`` is the same office everywhere,
whatever numpy's generators do in future releases. Run only to change the reference on purpose.
"""

import argparse
from pathlib import Path

from simn_sim.env.layout import generate_layout

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "envs" / "office_reference.json",
    )
    a = ap.parse_args()
    layout = generate_layout(a.seed)
    layout.save(a.out)
    print(
        f"wrote {a.out}: {layout.size[0]} x {layout.size[1]} m, {len(layout.rooms)} rooms, "
        f"{len(layout.doors)} doors, {len(layout.boxes)} boxes"
    )
