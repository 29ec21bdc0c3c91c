"""Forgetting of the learned map inside the SLAM pipeline (continual learning across frames).

:func:`measure_forgetting` runs :class:`~simn_sim.slam.pipeline.SimnSlam` with the learned
(implicit) map on a rendered sequence of an :class:`~simn_sim.geometry.analytic.AnalyticScene`
(exact depth, exact SDF) that opens several local frames: the camera turns in place, so each
local frame sees its own part of the room. When a local frame closes, its map's SDF error
(mean ``|F_theta - true SDF|`` at points near the surface it observed, in its anchor
coordinates) is taken; the first frame's error is taken again each time a later frame closes.
A closed frame's neural points and features never change, so the growth of its error is the
change of the decoder: forgetting. Variants (:data:`VARIANTS`): one decoder shared by the
frames with replay and EWC (the default), with replay only, with EWC only, with neither, and a
copy of the decoder per frame (the reference: a closed frame's decoder never changes).

The query points of a frame are its observations' surface points (rendered at the true poses)
moved along the viewing ray by ``U(-band, band)``, kept where ``|true SDF| <= band``. Revisit
checks are off and the motion prior is the exact pose increment, so the anchors are the true
first poses of the frames up to tracking error, which the error at close already contains.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from simn_sim.geometry.analytic import AnalyticScene, Box, Sphere
from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.slam.config import SlamConfig
from simn_sim.tracking.synthetic import look_at

__all__ = [
    "VARIANTS",
    "base_config",
    "ForgettingSetup",
    "forgetting_scene",
    "measure_forgetting",
    "variant_config",
]

# name -> (share_decoder, use_replay, use_ewc)
VARIANTS: dict[str, tuple[bool, bool, bool]] = {
    "shared+replay+ewc": (True, True, True),
    "shared+replay": (True, True, False),
    "shared+ewc": (True, False, True),
    "shared": (True, False, False),
    "copy per frame": (False, True, True),
}


def forgetting_scene() -> AnalyticScene:
    """A 6 x 5 x 2.6 m room whose parts differ: boxes of several sizes, spheres, a pillar."""
    return AnalyticScene(
        room=Box((0.0, 0.0, 1.3), (3.0, 2.5, 1.3)),
        boxes=(
            Box((2.2, 0.9, 0.4), (0.5, 0.4, 0.4)),
            Box((2.4, -1.0, 0.75), (0.3, 0.6, 0.75)),
            Box((-0.8, 1.9, 0.25), (0.7, 0.35, 0.25)),
            Box((-2.3, -1.2, 1.0), (0.4, 0.4, 1.0)),
            Box((0.6, -2.1, 0.5), (0.5, 0.25, 0.5)),
        ),
        spheres=(Sphere((1.0, 1.8, 0.6), 0.35), Sphere((-2.0, 1.0, 0.4), 0.4)),
    )


@dataclasses.dataclass(frozen=True)
class ForgettingSetup:
    """The sequence: ``n_obs`` views from ``eye`` turning by ``deg_per_obs`` about z (starting
    towards +x, looking ``pitch_deg`` down; ``first_deg_per_obs`` while the first frame is
    open), rendered at ``width`` x ``height`` (vertical field of view ``fovy_deg``); a local
    frame closes after ``frame_deg`` of turning."""

    n_obs: int = 42
    deg_per_obs: float = 6.0
    frame_deg: float = 30.0
    # the first local frame's views turn by this instead (0: deg_per_obs); smaller steps give
    # the first frame more observations, so it is learned further before it closes
    first_deg_per_obs: float = 0.0
    width: int = 120
    height: int = 90
    fovy_deg: float = 58.0
    eye: tuple[float, float, float] = (0.0, 0.0, 1.3)
    pitch_deg: float = 20.0
    band: float = 0.1  # query points within this distance of the surface (m)
    queries_per_view: int = 800
    # colour: the walls and objects are painted with a hue that turns with the azimuth around
    # the eye (each local frame sees its own colours, a shift of the decoder's colour input);
    # False: no RGB (every point grey)
    color: bool = False
    seed: int = 0

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fovy(self.width, self.height, self.fovy_deg)

    def poses(self) -> list[np.ndarray]:
        eye = np.asarray(self.eye, float)
        out = []
        step0 = self.first_deg_per_obs or self.deg_per_obs
        deg = 0.0
        for _ in range(self.n_obs):
            a = np.radians(deg)
            deg += step0 if deg <= self.frame_deg else self.deg_per_obs
            d = np.array([np.cos(a), np.sin(a), -np.tan(np.radians(self.pitch_deg))])
            out.append(look_at(eye, eye + d))
        return out


def painted_rgb(scene: AnalyticScene, intr: Intrinsics, T: np.ndarray, eye) -> np.ndarray:
    """(H, W, 3) uint8: each surface point's colour from its azimuth around ``eye`` (hue) and
    its height (value)."""
    import colorsys

    depth = scene.render_depth(intr, T)
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    z = np.where(np.isfinite(depth), depth, 0.0)
    pc = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], -1)
    p = transform_points(T, pc.reshape(-1, 3).astype(np.float64))
    az = np.arctan2(p[:, 1] - eye[1], p[:, 0] - eye[0]) % (2 * np.pi)
    val = 0.55 + 0.4 * np.clip(p[:, 2] / 2.6, 0, 1)
    hsv_to_rgb = np.vectorize(colorsys.hsv_to_rgb)
    r, g, b = hsv_to_rgb(az / (2 * np.pi), 0.8, val)
    return (255 * np.stack([r, g, b], -1)).reshape(intr.height, intr.width, 3).astype(np.uint8)


def base_config(
    preset: str = "default",
    batch: int = 0,
    seed: int = 0,
    open_iters: int = 0,
    train_iters: int = 0,
) -> SlamConfig:
    """The learned map's pipeline config for the measurement. ``default``: ``SlamConfig()``'s
    training (the adaptive loop stops when the windowed loss change falls below 1e-4);
    ``converged``: every training call runs its whole budget (loss threshold 0), so each frame
    is learned further before it closes and the decoder moves further on later frames.
    ``batch``, ``open_iters``, ``train_iters``: training batch, ``open_train_iters``,
    ``train_iters`` (0: the config's); ``seed``: the pipeline's and the mapper's seed."""
    if preset not in ("default", "converged"):
        raise ValueError(f"preset must be 'default' or 'converged', got {preset!r}")
    d = SlamConfig().to_dict()
    tr = d["mapper"]["training"]
    if preset == "converged":
        tr["loss_threshold"] = 0.0
    if batch:
        tr["batch_size"] = batch
    d["mapper"]["seed"] = d["seed"] = seed
    if open_iters:
        d["open_train_iters"] = open_iters
    if train_iters:
        d["train_iters"] = train_iters
    return SlamConfig.from_dict(d)


def variant_config(
    base: SlamConfig, share_decoder: bool, use_replay: bool, use_ewc: bool, frame_deg: float
) -> SlamConfig:
    """``base`` with the variant's decoder sharing, replay and EWC; revisits off, frames closed
    by turning only (``frame_deg``)."""
    d = base.to_dict()
    d["map_kind"] = "implicit"
    d["share_decoder"] = share_decoder
    d["revisits"] = False
    d["trigger"] = {**d["trigger"], "max_rotation_deg": frame_deg, "max_travel_m": 100.0}
    tr = d["mapper"]["training"]
    d["mapper"]["training"] = {**tr, "use_replay": use_replay, "use_ewc": use_ewc}
    return SlamConfig.from_dict(d)


def _queries(scene, intr, T, depth, n, band, rng) -> tuple[np.ndarray, np.ndarray]:
    """Near-surface points of one view (world) and their exact SDF."""
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    sel = rng.choice(len(u), min(n, len(u)), replace=False)
    u, v = u[sel], v[sel]
    z = depth[v, u].astype(np.float64)
    pc = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], 1)
    p = transform_points(T, pc)
    ray = (p - T[:3, 3]) / np.linalg.norm(p - T[:3, 3], axis=1, keepdims=True)
    q = p + rng.uniform(-band, band, (len(p), 1)) * ray
    t = scene.sdf(q)
    keep = np.abs(t) <= band
    return q[keep], t[keep]


def _frame_error(slam, fid: int, qw: np.ndarray, qt: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean |SDF error| of frame ``fid``'s map at world points (and the valid mask)."""
    m = slam.frames.states[fid].frame.map
    qa = transform_points(inv_T(slam.topo.anchor(fid)), qw).astype(np.float32)
    s = np.asarray(m.sdf(qa), np.float64)
    ok = np.isfinite(s)
    return float(np.abs(s[ok] - qt[ok]).mean()) if ok.any() else float("nan"), ok


def measure_forgetting(
    base: SlamConfig | None = None,
    setup: ForgettingSetup | None = None,
    variants: dict[str, tuple[bool, bool, bool]] | None = None,
    scene: AnalyticScene | None = None,
    log=None,
) -> dict[str, Any]:
    """Run each variant on the sequence; returns ``{"setup", "variants": {name: result}}``.

    A result: ``first_err_close`` (first frame's error right after it closed, m),
    ``first_err_after`` (its error after each later frame closed: index k = k + 1 later
    frames), ``forgetting`` (the last of those minus the error at close), ``forgetting_mean``
    and ``forgetting_max`` (their mean and largest minus the error at close; the error of a
    decoder that is still learning swings from one training call to the next, so the mean over
    the later closes is the steadier figure), ``own_err_close`` (each
    closed frame's error right after it closed: how well the new frames were learned),
    ``n_queries`` (of the first frame), ``local_frames`` and ``seconds`` (the run)."""
    from simn_sim.slam.pipeline import SimnSlam

    base = base or SlamConfig()
    setup = setup or ForgettingSetup()
    variants = VARIANTS if variants is None else variants
    scene = scene or forgetting_scene()
    intr = setup.intrinsics
    poses = setup.poses()
    depths = [scene.render_depth(intr, T) for T in poses]
    rgbs = [painted_rgb(scene, intr, T, setup.eye) if setup.color else None for T in poses]
    rng = np.random.default_rng(setup.seed)
    queries = [_queries(scene, intr, T, d, setup.queries_per_view, setup.band, rng)
               for T, d in zip(poses, depths, strict=True)]  # fmt: skip
    out: dict[str, Any] = {"setup": dataclasses.asdict(setup), "variants": {}}
    for name, (share, replay, ewc) in variants.items():
        cfg = variant_config(base, share, replay, ewc, setup.frame_deg)
        slam = SimnSlam(cfg, intr)
        frame_of: list[int] = []  # local frame of each processed view
        fixed: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # the queries valid at close
        first_after: list[float] = []
        own: list[float] = []
        close = slam.frames.close

        def closing(fid: int, close=close, slam=slam, frame_of=frame_of, fixed=fixed,
                    first_after=first_after, own=own) -> None:  # fmt: skip
            close(fid)
            views = [k for k, f in enumerate(frame_of) if f == fid]
            qw = np.concatenate([queries[k][0] for k in views])
            qt = np.concatenate([queries[k][1] for k in views])
            err, ok = _frame_error(slam, fid, qw, qt)
            fixed[fid] = (qw[ok], qt[ok])
            own.append(err)
            if fid > 0:
                first_after.append(_frame_error(slam, 0, *fixed[0])[0])

        slam.frames.close = closing
        t0 = time.perf_counter()
        for k, (T, d) in enumerate(zip(poses, depths, strict=True)):
            res = slam.process(0.1 * k, rgbs[k], d, T)
            frame_of.append(res.frame_id)
        sec = time.perf_counter() - t0
        if not first_after:
            raise ValueError("the sequence closed fewer than two local frames")
        r = {
            "share_decoder": share,
            "use_replay": replay,
            "use_ewc": ewc,
            "first_err_close": own[0],
            "first_err_after": first_after,
            "forgetting": first_after[-1] - own[0],
            "forgetting_mean": float(np.mean(first_after)) - own[0],
            "forgetting_max": float(np.max(first_after)) - own[0],
            "own_err_close": own,
            "n_queries": int(len(fixed[0][0])),
            "local_frames": len(slam.frames),
            "seconds": sec,
        }
        out["variants"][name] = r
        if log is not None:
            log(
                f"{name}: first frame {1e3 * r['first_err_close']:.2f} mm at close, "
                f"{1e3 * first_after[-1]:.2f} mm after {len(first_after)} later frames "
                f"({sec:.0f} s)"
            )
    return out
