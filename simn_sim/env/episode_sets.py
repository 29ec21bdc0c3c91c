"""Build fixed episode sets from the layout geometry (``simn-sim episodes --pool K``).

Per layout, ``pool`` candidates are drawn exactly as :meth:`SimnOfficeEnv._sample_episode` draws
one episode (a start with clearance ``ROBOT_RADIUS + start_clearance``, 32 goal candidates with
the same clearance, the first whose exact geodesic distance lies in the range, a uniform yaw),
from a generator seeded by ``(seed, layout)``. Each candidate is classified by
:func:`simn_sim.env.traps.trap_info` (only candidates with detour ratio >= 1.5 can be traps).
Then ``n`` are chosen per layout:

1. the layout's share of ``min_traps`` trap candidates, taken round-robin over the geodesic bins
   (``bins`` equal-width bins of ``[min_geodesic, max_geodesic]``), in draw order within a bin;
2. the rest one at a time from the bin with the fewest chosen so far (ties: the lower bin), in
   draw order within the bin, so the set spreads over the whole range.

The chosen episodes keep their draw order. Trap episodes carry ``tags: ["trap"]``. With
``people_clearance > 0`` (dynamic office) each episode's seed is moved (``+ 1_000_000`` per try)
until no person the env spawns at ``reset(seed)`` stands within that distance of the start.
Everything is deterministic: the same arguments give a byte-identical file.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from simn_sim.env.episodes import EpisodeSet, EpisodeSpec
from simn_sim.env.layout import Layout
from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND
from simn_sim.env.traps import MIN_DETOUR_RATIO, trap_info, wall_segments
from simn_sim.geometry.freespace import FreeSpace2D

TRAP_TAG = "trap"
_SEED_STEP = 1_000_000  # an episode seed moved for people clearance: + this per try


@dataclasses.dataclass(frozen=True)
class Candidate:
    start: tuple[float, float, float]
    goal: tuple[float, float]
    geodesic_m: float
    trap: bool


def layout_free_space(layout: Layout) -> FreeSpace2D:
    """The free space the env builds for a layout (robot disc, robot z band, office bounds)."""
    return FreeSpace2D(layout.footprints(ROBOT_Z_BAND), ROBOT_RADIUS, bounds=layout.bounds)


def sample_candidates(
    layout: Layout,
    fs: FreeSpace2D,
    rng: np.random.Generator,
    n: int,
    min_geodesic: float,
    max_geodesic: float,
    start_clearance: float,
) -> list[Candidate]:
    """``n`` candidates, each drawn by the env sampler's rules (module docstring)."""
    margin = ROBOT_RADIUS + start_clearance
    walls = wall_segments(layout)
    out: list[Candidate] = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 200 * max(n, 1):
            raise RuntimeError(
                f"layout {layout.layout_seed}: could not sample {n} start/goal pairs with "
                f"geodesic in [{min_geodesic}, {max_geodesic}] m"
            )
        s = fs.sample_free(rng, 1, min_clearance=margin)[0]
        field = fs.distance_field_to(s)
        cands = fs.sample_free(rng, 32, min_clearance=margin)
        d = field.distance(cands)
        ok = np.flatnonzero((d >= min_geodesic) & (d <= max_geodesic))
        if not len(ok):
            continue
        g = cands[ok[0]]
        yaw = float(rng.uniform(-math.pi, math.pi))
        geo = float(d[ok[0]])
        trap = False
        if geo >= MIN_DETOUR_RATIO * float(np.hypot(*(g - s))):
            trap = trap_info(layout, fs, s, g, walls).is_trap
        out.append(
            Candidate((float(s[0]), float(s[1]), yaw), (float(g[0]), float(g[1])), geo, trap)
        )
    return out


def select(
    cands: Sequence[Candidate],
    n: int,
    n_traps: int,
    min_geodesic: float,
    max_geodesic: float,
    bins: int,
) -> list[int]:
    """Indices of the ``n`` chosen candidates in draw order (module docstring, steps 1-2)."""
    if n > len(cands):
        raise ValueError(f"cannot choose {n} episodes from a pool of {len(cands)}")
    edges = np.linspace(min_geodesic, max_geodesic, bins + 1)
    b_of = [
        int(np.clip(np.searchsorted(edges, c.geodesic_m, "right") - 1, 0, bins - 1)) for c in cands
    ]
    chosen: list[int] = []
    count = [0] * bins

    def take(pred: Callable[[int], bool], order: list[int]) -> bool:
        for b in order:
            for i in range(len(cands)):
                if b_of[i] == b and i not in chosen and pred(i):
                    chosen.append(i)
                    count[b] += 1
                    return True
        return False

    b = 0
    misses = 0
    while sum(cands[i].trap for i in chosen) < min(n_traps, n) and misses < bins:
        if take(lambda i: cands[i].trap, [b]):
            misses = 0
        else:
            misses += 1
        b = (b + 1) % bins
    while len(chosen) < n:
        order = sorted(range(bins), key=lambda k: (count[k], k))
        take(lambda i: True, order)
    return sorted(chosen)


def trap_quotas(available: Sequence[int], total: int) -> list[int]:
    """Split ``total`` traps over layouts as evenly as possible (the first layouts take the
    remainder), moving a layout's shortfall (fewer trap candidates than its share) on to the
    next layouts with spare ones. ValueError when the pools hold fewer than ``total``."""
    n = len(available)
    if sum(available) < total:
        raise ValueError(
            f"the candidate pools hold {sum(available)} trap episodes ({list(available)} per "
            f"layout), fewer than --min-traps {total}; draw a larger --pool"
        )
    q = [total // n + (1 if k < total % n else 0) for k in range(n)]
    q = [min(qk, a) for qk, a in zip(q, available, strict=True)]
    short = total - sum(q)
    for k in range(n):
        extra = min(short, available[k] - q[k])
        q[k] += extra
        short -= extra
    return q


def build_episode_set(
    env_id: str,
    layouts: Sequence[int | None],
    n: int,
    seed: int,
    prefix: str,
    min_geodesic: float,
    max_geodesic: float,
    pool: int,
    bins: int = 4,
    min_traps: int = 0,
    start_clearance: float = 0.15,
    people_clearance: float = 0.0,
    load: Callable[[int | None], Layout] | None = None,
    progress: Callable[[int], None] | None = None,
) -> EpisodeSet:
    """The episode set of ``simn-sim episodes --pool`` (module docstring)."""
    from simn_sim.env.office import load_layout

    load = load or load_layout
    if pool < n:
        raise ValueError(f"--pool {pool} must be at least --n {n}")
    if bins < 1:
        raise ValueError(f"--geodesic-bins must be >= 1, got {bins}")
    pools = []
    for lay in layouts:
        key = 0 if lay is None else lay + 1
        layout = load(lay)
        rng = np.random.default_rng([int(seed), key, 0xE915])
        cands = sample_candidates(
            layout,
            layout_free_space(layout),
            rng,
            pool,
            min_geodesic,
            max_geodesic,
            start_clearance,
        )
        pools.append(cands)
        if progress is not None:
            progress(1)
    quotas = trap_quotas([sum(c.trap for c in p) for p in pools], min_traps)
    eps: list[EpisodeSpec] = []
    for lay, cands, q in zip(layouts, pools, quotas, strict=True):
        tag = "ref" if lay is None else f"L{lay}"
        base = seed * 10007 + (0 if lay is None else lay + 1) * 1000
        for i, k in enumerate(select(cands, n, q, min_geodesic, max_geodesic, bins)):
            c = cands[k]
            eps.append(
                EpisodeSpec(
                    f"{prefix}-{tag}-{i:03d}",
                    lay,
                    c.start,
                    c.goal,
                    base + i,
                    tags=(TRAP_TAG,) if c.trap else (),
                )
            )
    if people_clearance > 0:
        eps = _clear_people(env_id, eps, people_clearance)
    return EpisodeSet(env_id, eps)


def people_at_reset(env, spec: EpisodeSpec) -> np.ndarray:
    """(P, 2) positions of the people ``env`` spawns when reset with ``spec`` and its seed."""
    env.reset(seed=spec.seed, options={"episode": spec.to_dict()})
    return np.asarray(env.unwrapped._people.pos, float).reshape(-1, 2)


def _clear_people(env_id: str, eps: list[EpisodeSpec], clearance: float) -> list[EpisodeSpec]:
    import gymnasium as gym

    import simn_sim  # noqa: F401  (registers the env ids)

    env = gym.make(env_id, config={"width": 64, "height": 48})
    try:
        out = []
        for e in eps:
            for k in range(100):
                cand = dataclasses.replace(e, seed=e.seed + k * _SEED_STEP)
                pos = people_at_reset(env, cand)
                d = np.hypot(*(pos - np.asarray(e.start[:2])).T) if len(pos) else np.inf
                if np.all(d >= clearance):
                    out.append(cand)
                    break
            else:
                raise RuntimeError(f"{e.episode_id}: people always spawn near the start")
        return out
    finally:
        env.close()
