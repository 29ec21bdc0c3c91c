"""Reading and writing an :class:`~simn_sim.mapping.mapper.ImplicitMap` (a ``torch.save`` dict
with a format tag and version), and the maps of several local frames that share a decoder.

One map (:func:`map_state` / :func:`load_map`): config, decoder, neural points, EWC, this
frame's replay pool and the closed frames' replay. A map loaded alone owns its decoder.

Local frames sharing one decoder (:func:`save_frame_maps` / :func:`load_frame_maps`): one file
holds each shared part once per group of maps that share it (decoder, EWC state, closed
frames' replay) and, per frame, its own parts (neural points, replay pool, frame count); loading
restores the sharing, so training a loaded frame goes on protecting the others. Saving each
such frame with :meth:`ImplicitMap.save` instead would write the decoder once per frame, and
loading those files would give each frame its own copy."""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from simn_sim.mapping.config import MapperConfig

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap

__all__ = [
    "FRAMES_FORMAT",
    "MAP_FORMAT",
    "MAP_VERSION",
    "MapFileError",
    "load_frame_maps",
    "load_map",
    "map_state",
    "save_frame_maps",
]

MAP_FORMAT = "simn-sim/implicit-map"
MAP_VERSION = 1
FRAMES_FORMAT = "simn-sim/implicit-frames"

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


def _cpu(x):
    """Tensors (in dicts / lists / tuples) moved to the CPU, for a device-independent file."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu()
    if isinstance(x, dict):
        return {k: _cpu(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return type(x)(_cpu(v) for v in x)
    return x


def _shared_state(m: ImplicitMap) -> dict:
    """What maps sharing ``m.decoder`` share: decoder, EWC, closed frames' replay."""
    return {
        "decoder": _cpu(m.decoder.state_dict()),
        "ewc": _cpu(m.ewc.state_dict()),
        "frame_replay": _cpu(m.frame_replay.state_dict()),
    }


def _own_state(m: ImplicitMap) -> dict:
    """What is the map's alone: config, neural points, its replay pool, frame count."""
    p = m.points
    return {
        "config": m.cfg.to_dict(),
        "points": _cpu(
            {
                "positions": p.positions,
                "features": p.features,
                "colors": p.colors,
                "labels": p.labels,
                "plane_sum": p.plane_sum,
                "normal_sum": p.normal_sum,
                "plane_count": p.plane_count,
            }
        ),
        "replay": _cpu(m.replay.state_dict()),
        "frame_count": m.frame_count,
    }


def map_state(m: ImplicitMap) -> dict:
    """The map as a dict of tensors and plain values (what :meth:`ImplicitMap.save` writes)."""
    return {"format": MAP_FORMAT, "version": MAP_VERSION, **_own_state(m), **_shared_state(m)}


def _read(path: str | Path, fmt: str, what: str) -> tuple[Path, dict]:
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"{path}: no such map file")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except _UNREADABLE as e:
        raise MapFileError(
            f"{path}: not a readable simn-sim map file ({type(e).__name__}: {e})"
        ) from e
    if not isinstance(state, dict) or state.get("format") != fmt:
        raise MapFileError(f"{path}: not a simn-sim {what} (missing format tag {fmt!r})")
    if state.get("version") != MAP_VERSION:
        raise MapFileError(f"{path}: map format version {state.get('version')} is not supported")
    return path, state


def _config(state: dict, device: str | None) -> MapperConfig:
    cfg = MapperConfig.from_dict(state["config"])
    return cfg if device is None else cfg.replace(device=device)


def _set_shared(m: ImplicitMap, state: dict) -> None:
    m.decoder.load_state_dict(state["decoder"])
    m.ewc.load_state_dict(state["ewc"])
    if m.ewc.fisher is not None:
        m.ewc.fisher = {k: v.to(m.device) for k, v in m.ewc.fisher.items()}
        m.ewc.anchor = {k: v.to(m.device) for k, v in m.ewc.anchor.items()}
    if "frame_replay" in state:  # absent in files written before replay across frames
        m.frame_replay.load_state_dict(state["frame_replay"])


def _set_own(m: ImplicitMap, state: dict) -> None:
    pts = state["points"]
    planes = None
    if "plane_sum" in pts:
        planes = (pts["plane_sum"], pts["normal_sum"], pts["plane_count"])
    m.points.set_state(pts["positions"], pts["features"], pts["colors"], pts["labels"], planes)
    m.replay.load_state_dict(state["replay"])
    m.frame_count = int(state["frame_count"])


_CORRUPT = (KeyError, TypeError, ValueError, RuntimeError, IndexError)


def load_map(cls: type[ImplicitMap], path: str | Path, device: str | None = None) -> ImplicitMap:
    """Read a map written by :meth:`save`. Raises :class:`MapFileError` when the file is
    missing, corrupt, or not a simn-sim implicit map."""
    path, state = _read(path, MAP_FORMAT, "implicit map")
    try:
        m = cls(_config(state, device))
        _set_shared(m, state)
        _set_own(m, state)
    except _CORRUPT as e:
        raise MapFileError(f"{path}: corrupt simn-sim map ({type(e).__name__}: {e})") from e
    return m


def save_frame_maps(maps: dict[int, ImplicitMap], path: str | Path) -> Path:
    """Write the maps of several local frames (``{frame id: map}``) to one file, each decoder
    (with its EWC state and closed frames' replay) once for the maps that share it."""
    groups: list[ImplicitMap] = []  # the first map of each decoder
    frames = {}
    for fid, m in maps.items():
        g = next((i for i, h in enumerate(groups) if h.decoder is m.decoder), None)
        if g is None:
            g = len(groups)
            groups.append(m)
        frames[int(fid)] = {"shared": g, **_own_state(m)}
    state = {
        "format": FRAMES_FORMAT,
        "version": MAP_VERSION,
        "shared": [_shared_state(h) for h in groups],
        "frames": frames,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, path)
    return path


def load_frame_maps(
    cls: type[ImplicitMap], path: str | Path, device: str | None = None
) -> dict[int, ImplicitMap]:
    """Read maps written by :func:`save_frame_maps`: ``{frame id: map}``, the maps that shared
    a decoder sharing it again (with its EWC state, closed frames' replay and one generator
    seeded with the config's seed). Raises :class:`MapFileError` as :func:`load_map`."""
    path, state = _read(path, FRAMES_FORMAT, "set of local-frame maps")
    out: dict[int, ImplicitMap] = {}
    try:
        first: dict[int, ImplicitMap] = {}
        for fid, st in sorted(state["frames"].items()):
            g = int(st["shared"])
            if g in first:
                m = first[g].new_map(share_decoder=True)  # the group's config and generator
            else:
                m = first[g] = cls(_config(st, device))
                _set_shared(m, state["shared"][g])
            _set_own(m, st)
            out[int(fid)] = m
    except _CORRUPT as e:
        raise MapFileError(f"{path}: corrupt simn-sim map ({type(e).__name__}: {e})") from e
    return out
