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
* :func:`read_rows`: the logged rows (step or ``None`` for static, component values) per entity.
* :func:`world_positions`: every logged 3-D position (points, line strip vertices, shape centres,
  arrow origins, transform origins) mapped into the root frame through the entity's ancestors'
  ``Transform3D`` (latest at that step), e.g. to check that everything lies in the building.

Command line: ``python -m simn_sim.experiments.rrd FILE.rrd`` prints the summary.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

__all__ = [
    "RecordingSummary",
    "entity_translations",
    "read_recording",
    "read_rows",
    "world_positions",
]

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
            s = self.steps_per_entity.get(e, [])
            parts = ["static"] if e in self.static_entities else []
            if s or not parts:
                parts.append(f"{len(s)} steps" + (f" [{s[0]}..{s[-1]}]" if s else ""))
            what = " + ".join(parts)
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


Row = tuple[int | None, dict[str, list]]

# component column suffixes that hold 3-D positions in the entity's own coordinates
POSITION_COMPONENTS = (":positions", ":strips", ":centers", ":origins")
_TRANSFORM_COMPONENTS = (":translation", ":mat3x3", ":quaternion")


def read_rows(
    path: str | Path, entities: list[str] | None = None, components: tuple[str, ...] | None = None
) -> dict[str, list[Row]]:
    """The rows of the first recording of an ``.rrd`` file, per entity.

    Args:
        entities: entity paths to read (without the leading ``/``); ``None``: all.
        components: keep only component columns whose name ends with one of these (e.g.
            ``(":positions",)``; names look like ``Points3D:positions``); ``None``: all (image
            blobs too, which is slow).

    Returns:
        entity -> [(step, {component column: the row's value (a list)})], static rows first
        (step ``None``), then by step; rows logged at the same step keep their logging order.
        Only rows with at least one of the wanted components are kept.
    """
    from rerun.chunk import RrdReader

    reader = RrdReader(Path(path))
    stores = reader.recordings()
    want = None if entities is None else {_norm(e) for e in entities}
    out: dict[str, list[tuple[tuple, int, int | None, dict]]] = {}
    order = 0
    for ch in reader.stream(store=stores[0]) if stores else []:
        ent = _norm(ch.entity_path)
        if ent.startswith("__") or (want is not None and ent not in want):
            continue
        rb = ch.to_record_batch()
        names = [
            n
            for n in rb.schema.names
            if ":" in n and (components is None or n.endswith(tuple(components)))
        ]
        if not names:
            continue
        if ch.is_static or STEP_TIMELINE not in rb.schema.names:
            steps = [None] * rb.num_rows
        else:
            steps = rb.column(STEP_TIMELINE).to_pylist()
        cols = {n: rb.column(n).to_pylist() for n in names}
        for i, st in enumerate(steps):
            vals = {n: c[i] for n, c in cols.items() if c[i] is not None}
            if vals:
                key = (0, 0) if st is None else (1, int(st))
                out.setdefault(ent, []).append((key, order, st, vals))
                order += 1
    return {
        e: [
            (None if st is None else int(st), v)
            for _, _, st, v in sorted(rows, key=lambda r: r[:2])
        ]
        for e, rows in sorted(out.items())
    }


def _latest_at(rows: list[Row], step: int | None) -> dict[str, list] | None:
    """Component values of the last row at or before ``step`` (static rows count as before
    everything; a row with only some components overrides only those)."""
    cur: dict[str, list] = {}
    for st, vals in rows:
        if st is not None and (step is None or st > step):
            break
        cur.update(vals)
    return cur or None


def _transform(vals: dict[str, list] | None) -> np.ndarray:
    T = np.eye(4)
    if not vals:
        return T
    for n, v in vals.items():
        if not v:
            continue
        if n.endswith(":translation"):
            T[:3, 3] = np.asarray(v[-1], float)
        elif n.endswith(":mat3x3"):  # rerun stores 3x3 matrices column-major
            T[:3, :3] = np.asarray(v[-1], float).reshape(3, 3).T
        elif n.endswith(":quaternion"):
            x, y, z, w = np.asarray(v[-1], float)
            T[:3, :3] = [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
    return T


def world_positions(path: str | Path) -> dict[str, list[tuple[int | None, np.ndarray]]]:
    """Every 3-D position of the recording in the root frame, per entity and logged row.

    Positions are the ``positions`` / ``strips`` (all vertices) / ``centers`` / ``origins``
    components of a row, and the origin of a ``Transform3D``; each is mapped through the
    ``Transform3D`` of its ancestors (and, for the non-transform components, of the entity
    itself), latest at the row's step; a static row below transforms logged over time is
    mapped at each of their steps. Entities below a ``Pinhole`` (image space) are skipped.

    Returns:
        entity -> [(step or None for static, (N, 3) float64 positions)].
    """
    rows = read_rows(
        path, components=POSITION_COMPONENTS + _TRANSFORM_COMPONENTS + (":image_from_camera",)
    )
    tf_rows = {
        e: [(s, {n: x for n, x in v.items() if n.endswith(_TRANSFORM_COMPONENTS)}) for s, v in r]
        for e, r in rows.items()
    }
    tf_rows = {e: [(s, v) for s, v in r if v] for e, r in tf_rows.items()}
    pinholes = {
        e for e, r in rows.items() if any(n.endswith(":image_from_camera") for _, v in r for n in v)
    }

    def chain(entity: str, step: int | None) -> np.ndarray:
        parts = entity.split("/")
        T = np.eye(4)
        for i in range(1, len(parts) + 1):
            anc = "/".join(parts[:i])
            if anc in tf_rows:
                T = T @ _transform(_latest_at(tf_rows[anc], step))
        return T

    def moving_steps(entity: str) -> list[int]:
        parts = entity.split("/")
        anc = ("/".join(parts[:i]) for i in range(1, len(parts) + 1))
        return sorted({s for a in anc for s, _ in tf_rows.get(a, []) if s is not None})

    out: dict[str, list[tuple[int | None, np.ndarray]]] = {}
    for e, r in rows.items():
        parts = e.split("/")
        if any("/".join(parts[:i]) in pinholes for i in range(1, len(parts))):
            continue
        parent = "/".join(parts[:-1])
        for st, vals in r:
            pts = []
            for n, v in vals.items():
                if n.endswith((":positions", ":centers", ":origins")):
                    pts.append(np.asarray(v, float).reshape(-1, 3))
                elif n.endswith(":strips"):
                    pts.extend(np.asarray(s, float).reshape(-1, 3) for s in v)
            if pts:
                P = np.concatenate(pts)
                # a static shape under moving transforms is drawn at each of their steps
                at = [st] if st is not None else (moving_steps(e) or [None])
                for s_ in at:
                    T = chain(e, s_)
                    out.setdefault(e, []).append((s_, P @ T[:3, :3].T + T[:3, 3]))
            if any(n.endswith(":translation") for n in vals):
                T = chain(parent, st) @ _transform(_latest_at(tf_rows[e], st))
                out.setdefault(e, []).append((st, T[:3, 3][None].copy()))
    return out


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
