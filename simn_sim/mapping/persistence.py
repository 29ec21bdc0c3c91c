"""Reading and writing an :class:`~simn_sim.mapping.mapper.ImplicitMap` (a ``torch.save`` dict
with a format tag and version)."""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from simn_sim.mapping.config import MapperConfig

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap

__all__ = ["MAP_FORMAT", "MAP_VERSION", "MapFileError", "load_map", "map_state"]

MAP_FORMAT = "simn-sim/implicit-map"
MAP_VERSION = 1

# what torch.load raises for a file that is not a readable map: bad pickle data or a tensor
# type outside weights_only (UnpicklingError), truncation (EOFError), a broken zip container
# (RuntimeError from the stream reader, BadZipFile), unreadable bytes (OSError, ValueError)
_UNREADABLE = (
    pickle.UnpicklingError,
    EOFError,
    RuntimeError,
    zipfile.BadZipFile,
    OSError,
    ValueError,
)


class MapFileError(ValueError):
    """A map file is missing, corrupt, or not a simn-sim implicit map."""


def map_state(m: ImplicitMap) -> dict:
    """The map as a dict of tensors and plain values (what :meth:`ImplicitMap.save` writes)."""
    p = m.points
    return {
        "format": MAP_FORMAT,
        "version": MAP_VERSION,
        "config": m.cfg.to_dict(),
        "decoder": {k: v.detach().cpu() for k, v in m.decoder.state_dict().items()},
        "points": {
            "positions": p.positions.cpu(),
            "features": p.features.cpu(),
            "colors": p.colors.cpu(),
            "labels": p.labels.cpu(),
            "plane_sum": p.plane_sum.cpu(),
            "normal_sum": p.normal_sum.cpu(),
            "plane_count": p.plane_count.cpu(),
        },
        "ewc": m.ewc.state_dict(),
        "replay": m.replay.state_dict(),
        "frame_count": m.frame_count,
    }


def load_map(cls: type[ImplicitMap], path: str | Path, device: str | None = None) -> ImplicitMap:
    """Read a map written by :meth:`save`. Raises :class:`MapFileError` when the file is
    missing, corrupt, or not a simn-sim implicit map."""
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"{path}: no such map file")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except _UNREADABLE as e:
        raise MapFileError(
            f"{path}: not a readable simn-sim map file ({type(e).__name__}: {e})"
        ) from e
    if not isinstance(state, dict) or state.get("format") != MAP_FORMAT:
        raise MapFileError(
            f"{path}: not a simn-sim implicit map (missing format tag {MAP_FORMAT!r})"
        )
    if state.get("version") != MAP_VERSION:
        raise MapFileError(f"{path}: map format version {state.get('version')} is not supported")
    try:
        cfg = MapperConfig.from_dict(state["config"])
        if device is not None:
            cfg = cfg.replace(device=device)
        m = cls(cfg)
        m.decoder.load_state_dict(state["decoder"])
        pts = state["points"]
        planes = None
        if "plane_sum" in pts:
            planes = (pts["plane_sum"], pts["normal_sum"], pts["plane_count"])
        m.points.set_state(pts["positions"], pts["features"], pts["colors"], pts["labels"], planes)
        m.ewc.load_state_dict(state["ewc"])
        if m.ewc.fisher is not None:
            m.ewc.fisher = {k: v.to(m.device) for k, v in m.ewc.fisher.items()}
            m.ewc.anchor = {k: v.to(m.device) for k, v in m.ewc.anchor.items()}
        m.replay.load_state_dict(state["replay"])
        m.frame_count = int(state["frame_count"])
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise MapFileError(f"{path}: corrupt simn-sim map ({type(e).__name__}: {e})") from e
    return m
