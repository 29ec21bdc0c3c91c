"""Dataset input/output (TUM RGB-D format)."""
