"""Where the package's data lives: ``assets/`` (MJCF, textures) and ``envs/`` (scene and episode specs).

An installed wheel carries them in ``simn_sim/_data``; an editable install or a source checkout
reads them from the repository root.
"""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _data_root(name: str) -> Path:
    for cand in (_PKG / "_data" / name, _PKG.parent / name):
        if cand.is_dir():
            return cand
    raise FileNotFoundError(
        f"simn_sim data folder '{name}' not found (looked in {_PKG / '_data' / name} and "
        f"{_PKG.parent / name}); the installation is incomplete"
    )


def assets_dir() -> Path:
    return _data_root("assets")


def envs_dir() -> Path:
    return _data_root("envs")
