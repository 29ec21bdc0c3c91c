"""Read a rerun recording (``.rrd``) of an episode back: entity paths, time steps, poses.

rerun 0.41 has no ``rerun.dataframe`` module any more; recordings are read with
``rerun.chunk.RrdReader``, which streams the recording's chunks (each chunk holds rows of one
entity, as an Arrow record batch with one column per timeline and per component). This module
wraps that into a few plain answers:

* :func:`read_recording` -> :class:`RecordingSummary`: every entity path (without the leading
  ``/``, as the recorder logs them, e.g. ``world/robot``), which ones are static, the ``step``
  values present per entity and overall.
* :func:`entity_translations`: the ``Transform3D`` translations of one entity per step (e.g. the
  true base positions of ``world/robot``).

Command line: ``python -m simn_sim.experiments.rrd FILE.rrd`` prints the summary.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

__all__ = ["RecordingSummary", "entity_translations", "read_recording"]

STEP_TIMELINE = "step"


@dataclasses.dataclass(frozen=True)
class RecordingSummary:
    """What one ``.rrd`` file holds.

    Attributes:
        path: the file.
        application_id, recording_id: of the (first) recording store in the file.
        entity_paths: sorted entity paths, without the leading ``/`` (``world/robot``);
            rerun's own ``__properties`` entity is left out.
        static_entities: the entity paths logged with ``static=True`` (no timeline).
        steps_per_entity: entity path -> sorted distinct values of the ``step`` timeline.
        steps: sorted distinct ``step`` values over all entities.
        n_rows: entity path -> number of logged rows (over all chunks).
    """

    path: Path
    application_id: str
    recording_id: str
    entity_paths: list[str]
    static_entities: list[str]
    steps_per_entity: dict[str, list[int]]
    steps: list[int]
    n_rows: dict[str, int]

    @property
    def n_steps(self) -> int:
        """Number of distinct ``step`` values (an episode of ``k`` env steps logs ``k + 1``)."""
        return len(self.steps)

    def format(self) -> str:
        """Human-readable listing, one entity per line."""
        lines = [
            f"{self.path}: recording {self.recording_id!r} ({self.application_id}), "
            f"{self.n_steps} steps"
            + (f" [{self.steps[0]}..{self.steps[-1]}]" if self.steps else "")
        ]
        for e in self.entity_paths:
            if e in self.static_entities:
                what = "static"
            else:
                s = self.steps_per_entity.get(e, [])
                what = f"{len(s)} steps" + (f" [{s[0]}..{s[-1]}]" if s else "")
            lines.append(f"  {e:40s} {self.n_rows.get(e, 0):6d} rows  {what}")
        return "\n".join(lines)


def _norm(entity_path: str) -> str:
    return entity_path.lstrip("/")


def read_recording(path: str | Path) -> RecordingSummary:
    """Summarise the first recording store of an ``.rrd`` file.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a readable rerun recording (the message names it).
    """
    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"recording {p} does not exist")
    try:
        reader = RrdReader(p)
        stores = reader.recordings()
        if not stores:
            raise ValueError(f"{p}: holds no recording store")
        chunks = list(reader.stream(store=stores[0]))
    except ValueError:
        raise
    except Exception as e:  # rerun raises its own error types for corrupt files
        raise ValueError(f"{p}: not a readable rerun recording ({type(e).__name__}: {e})") from e
    static: set[str] = set()
    steps: dict[str, set[int]] = {}
    rows: dict[str, int] = {}
    for ch in chunks:
        ent = _norm(ch.entity_path)
        if ent.startswith("__"):
            continue
        rows[ent] = rows.get(ent, 0) + ch.num_rows
        if ch.is_static:
            static.add(ent)
            continue
        if STEP_TIMELINE in ch.timeline_names:
            col = ch.to_record_batch().column(STEP_TIMELINE)
            steps.setdefault(ent, set()).update(int(v) for v in col.to_pylist() if v is not None)
    all_steps = sorted(set().union(*steps.values())) if steps else []
    return RecordingSummary(
        path=p,
        application_id=str(stores[0].application_id),
        recording_id=str(stores[0].recording_id),
        entity_paths=sorted(rows),
        static_entities=sorted(static),
        steps_per_entity={k: sorted(v) for k, v in sorted(steps.items())},
        steps=all_steps,
        n_rows=dict(sorted(rows.items())),
    )


def entity_translations(path: str | Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """``Transform3D`` translations of ``entity`` per step.

    Returns:
        (steps (N,) int64 sorted, translations (N, 3) float64, world frame); the last logged
        value wins where a step was logged twice.

    Raises:
        KeyError: the entity has no translation on the ``step`` timeline.
    """
    from rerun.chunk import RrdReader

    want = _norm(entity)
    by_step: dict[int, np.ndarray] = {}
    for ch in RrdReader(Path(path)).stream():
        if _norm(ch.entity_path) != want or ch.is_static:
            continue
        rb = ch.to_record_batch()
        names = rb.schema.names
        col = next((n for n in names if n.endswith(":translation")), None)
        if col is None or STEP_TIMELINE not in names:
            continue
        for s, t in zip(
            rb.column(STEP_TIMELINE).to_pylist(), rb.column(col).to_pylist(), strict=True
        ):
            if s is not None and t:
                by_step[int(s)] = np.asarray(t[-1], np.float64)
    if not by_step:
        raise KeyError(f"{path}: entity {entity!r} has no Transform3D translation on 'step'")
    keys = sorted(by_step)
    return np.asarray(keys, np.int64), np.stack([by_step[k] for k in keys])


def main(argv: list[str] | None = None) -> int:
    """Print the summary of each ``.rrd`` file given; exit 2 on an unreadable file."""
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print("usage: python -m simn_sim.experiments.rrd FILE.rrd [...]", file=sys.stderr)
        return 2
    status = 0
    for a in args:
        try:
            print(read_recording(a).format())
        except (OSError, ValueError) as e:
            print(f"error: {e}", file=sys.stderr)
            status = 2
    return status


if __name__ == "__main__":
    raise SystemExit(main())
