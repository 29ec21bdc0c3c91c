"""The spatial-implicit map of one local frame: neural points + decoder, trained continually.

:class:`ImplicitMap` owns a :class:`~simn_sim.mapping.neural_points.NeuralPointMap` (in the
map's own anchor coordinates) and a :class:`~simn_sim.mapping.decoder.Decoder` (which may be
shared with, or copied from, another map). Per frame it inserts neural points and draws ray
samples; every ``train_every``-th frame it runs the adaptive training loop on the new samples
mixed with a bounded replay pool, with the loss
``lambda_b BCE + lambda_e Eikonal + lambda_EWC EWC``.

Continual learning across local frames (:meth:`new_map` with ``share_decoder``): the maps
share the decoder, its :class:`~simn_sim.mapping.losses.EWC` state and a
:class:`~simn_sim.mapping.continual.FrameReplay`; each keeps its own neural points and its own
replay pool. :meth:`close` (a local frame closes) takes the diagonal Fisher on the frame's
samples, adds it to the shared one (summed over closed frames, anchored at the weights of the
latest close) and hands a share of the frame's samples, with their decoder inputs, to the
later frames' replay. Queries return the SDF, its gradient in
map coordinates and a validity mask (a point with no neural point within the search radius has
no SDF: NaN and ``valid = False``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from simn_sim.geometry.bounds import finite_rows
from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping.config import MapperConfig
from simn_sim.mapping.continual import FrameReplay
from simn_sim.mapping.decoder import Decoder
from simn_sim.mapping.decoding import decoder_inputs
from simn_sim.mapping.losses import EWC, bce_sdf_loss, diagonal_fisher
from simn_sim.mapping.neural_points import FeaturePoints, NeuralPointMap
from simn_sim.mapping.perception import (
    EmptyFrameError,
    estimate_normals,
    rgbd_to_points,
    voxel_downsample,
)
from simn_sim.mapping.persistence import (
    MAP_FORMAT,
    MAP_VERSION,
    MapFileError,
    load_frame_maps,
    load_map,
    map_state,
    save_frame_maps,
)
from simn_sim.mapping.replay import ReplayPool
from simn_sim.mapping.results import (
    FrameResult,
    SdfQuery,
    TrainResult,
    check_colors,
    check_labels,
    flush_denormals,
)
from simn_sim.mapping.results import as_float_points as _as_float_points
from simn_sim.mapping.sampling import sample_rays
from simn_sim.mapping.tracking_sdf import TrackingSdf
from simn_sim.mapping.training import train_chunk
from simn_sim.tracking.lie import check_pose

__all__ = [
    "MAP_FORMAT",
    "MAP_VERSION",
    "FrameResult",
    "ImplicitMap",
    "MapFileError",
    "SdfQuery",
    "TrackingSdf",
    "TrainResult",
    "check_pose",
    "estimate_normals",
    "flush_denormals",
    "save_frame_maps",
]


class ImplicitMap:
    """Neural points + decoder of one local frame, in that frame's (anchor) coordinates.

    Parameters
    ----------
    cfg: the mapper config (validated).
    decoder: share an existing decoder (e.g. the previous frame's, or ``other.decoder.copy()``);
        a new one is created when None.
    generator: torch RNG for feature init, ray sampling, batches and replay; by default one
        seeded with ``cfg.seed``.
    ewc, frame_replay: share the EWC state and the replay of closed frames of the maps that
        share ``decoder`` (:meth:`new_map`); new, empty ones when None.
    """

    def __init__(
        self,
        cfg: MapperConfig | None = None,
        decoder: Decoder | None = None,
        generator: torch.Generator | None = None,
        ewc: EWC | None = None,
        frame_replay: FrameReplay | None = None,
    ) -> None:
        self.cfg = cfg or MapperConfig()
        self.device = torch.device(self.cfg.device)
        if generator is None:
            generator = torch.Generator(device=self.device).manual_seed(self.cfg.seed)
        self.generator = generator
        self.points = NeuralPointMap(self.cfg.points, self.device, generator)
        if decoder is None:
            # the decoder is initialised on the CPU, so it needs a CPU generator
            gen = generator
            if generator.device.type != "cpu":
                gen = torch.Generator().manual_seed(self.cfg.seed)
            decoder = Decoder(self.cfg.decoder, self.cfg.points.feature_dim, gen).to(self.device)
        elif decoder.feature_dim != self.cfg.points.feature_dim:
            raise ValueError(
                f"decoder takes features of dim {decoder.feature_dim}, map has {self.cfg.points.feature_dim}"
            )
        self.decoder = decoder
        self.ewc = EWC() if ewc is None else ewc
        tc = self.cfg.training
        self.replay = ReplayPool(tc.replay_capacity, self.device)  # this frame's samples
        if frame_replay is None:
            frame_replay = FrameReplay(tc.frame_replay_capacity, self.device)
        self.frame_replay = frame_replay  # closed frames' samples (shared with the decoder)
        self._recent = ReplayPool(tc.fisher_samples, self.device)  # since the last consolidation
        self._pending: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        self._n_pending = 0
        self.frame_count = 0
        self.n_trainings = 0  # calls of train() that changed the map
        self.last_train: TrainResult | None = None

    # ------------------------------------------------------------------ integration
    def integrate_frame(
        self,
        points_cam: np.ndarray | torch.Tensor,
        T_map_cam: np.ndarray,
        colors: np.ndarray | torch.Tensor | None = None,
        labels: np.ndarray | torch.Tensor | None = None,
        train: bool | None = None,
        normals: np.ndarray | torch.Tensor | None = None,
    ) -> FrameResult:
        """Add one frame of camera-frame points seen from pose ``T_map_cam``.

        points_cam: (N, 3) float, OpenCV camera frame. colors: (N, 3) in [0, 1] (float) or
        uint8. labels: (N,) integer semantic labels (0 unknown). Non-finite points are dropped.
        normals: (N, 3) camera-frame surface normals (NaN: unknown), used by the decoder's
        geometric prior; when the prior is on and none are given they are estimated from the
        frame's points (PCA of the 8 nearest).
        ``train``: force (True) or skip (False) training; by default every ``train_every``-th
        frame trains. Raises :class:`EmptyFrameError` for a frame without a finite point.
        """
        T = check_pose(T_map_cam, "T_map_cam", tol=1e-4)
        pts = _as_float_points(points_cam, "points_cam").detach().cpu().numpy().astype(np.float32)
        n_in = pts.shape[0]
        if n_in == 0:
            raise EmptyFrameError("integrate_frame: the frame has no points")
        cols = check_colors(colors, n_in)
        labs = check_labels(labels, n_in)
        finite = finite_rows(pts)
        n_dropped = int(n_in - finite.sum())
        if n_dropped == n_in:
            raise EmptyFrameError(f"integrate_frame: all {n_in} points are NaN/inf")
        use_prior = self.decoder.cfg.geometric_prior
        nrm = None
        if use_prior and normals is not None:
            nrm = _as_float_points(normals, "normals").detach().cpu().numpy().astype(np.float32)
            if nrm.shape[0] != n_in:
                raise ValueError(f"normals must be ({n_in}, 3), got {nrm.shape}")
        if n_dropped:
            pts, cols = pts[finite], cols[finite]
            labs = None if labs is None else labs[finite]
            nrm = None if nrm is None else nrm[finite]
        full = (pts, nrm)  # the planes take every point with a normal, not the down-sampled
        if self.cfg.integrate_voxel_size > 0:
            if nrm is not None:  # average the normals with the colours (NaN rows: none)
                has = finite_rows(nrm)
                ext = np.concatenate([cols, np.where(has[:, None], nrm, 0.0)], 1)
                pts, ext, labs = voxel_downsample(pts, self.cfg.integrate_voxel_size, ext, labs)
                cols, nrm = ext[:, :3], ext[:, 3:]
                nn_ = np.linalg.norm(nrm, axis=1, keepdims=True)
                nrm = np.where(nn_ > 0.5, nrm / np.maximum(nn_, 1e-9), np.nan).astype(np.float32)
            else:
                pts, cols, labs = voxel_downsample(pts, self.cfg.integrate_voxel_size, cols, labs)
        if use_prior and nrm is None:
            nrm = estimate_normals(pts)
        pts_map = (pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
        dev = self.device
        p_t = torch.from_numpy(pts_map).to(dev)
        n_map = None
        if nrm is not None:
            n_map = torch.from_numpy((nrm.astype(np.float64) @ T[:3, :3].T).astype(np.float32))
        new_ids = self.points.add_points(
            p_t,
            torch.from_numpy(cols).to(dev),
            None if labs is None else torch.from_numpy(labs.astype(np.int16)).to(dev),
            None if (n_map is None or full[1] is not None) else n_map.to(dev),
        )
        if full[1] is not None:
            fp, fn = full
            has = finite_rows(fn)
            fp = (fp[has].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
            fn = (fn[has].astype(np.float64) @ T[:3, :3].T).astype(np.float32)
            self.points.accumulate_planes(
                torch.from_numpy(fp).to(dev), torch.from_numpy(fn).to(dev)
            )
        origin = torch.from_numpy(T[:3, 3].astype(np.float32)).to(dev)
        samples = sample_rays(
            p_t, origin, self.cfg.sampling, self.generator, None if n_map is None else n_map.to(dev)
        )
        self._add_pending(samples.points, samples.sdf, samples.kind)
        self.frame_count += 1
        do_train = (
            train if train is not None else self.frame_count % self.cfg.training.train_every == 0
        )
        tr = self.train() if do_train else None
        return FrameResult(
            self.frame_count - 1, len(pts_map), n_dropped, len(new_ids), len(samples), tr
        )

    def integrate_rgbd(
        self,
        depth: np.ndarray,
        intr: Intrinsics,
        T_map_cam: np.ndarray,
        rgb: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        train: bool | None = None,
    ) -> FrameResult:
        """Back-project (``cfg.perception``) and :meth:`integrate_frame`."""
        pc = rgbd_to_points(depth, intr, rgb, labels, self.cfg.perception)
        return self.integrate_frame(pc.points, T_map_cam, pc.colors, pc.labels, train=train)

    def _add_pending(self, x: torch.Tensor, s: torch.Tensor, k: torch.Tensor) -> None:
        self._pending.append((x, s, k))
        self._n_pending += x.shape[0]
        cap = self.cfg.training.max_pending
        if self._n_pending > cap:  # keep a uniform random subset
            X, S, K = (torch.cat(t) for t in zip(*self._pending, strict=True))
            sel = torch.randperm(X.shape[0], generator=self.generator, device=self.device)[:cap]
            self._pending = [(X[sel], S[sel], K[sel])]
            self._n_pending = cap

    @property
    def n_pending(self) -> int:
        """Samples waiting for the next training call."""
        return self._n_pending

    # ------------------------------------------------------------------ training
    def train(self, max_iters: int | None = None) -> TrainResult:
        """Adaptive training loop on the pending samples mixed with replayed ones.

        Stops when the mean loss of the last ``loss_window`` iterations differs from the
        window before by less than ``loss_threshold`` (after ``min_iters``), or at
        ``max_iters``. Features of the neural points touched by the batch and the decoder
        weights are updated by Adam. Afterwards the new samples join the replay pool.
        """
        res, apply = self.train_deferred(max_iters)
        apply()
        return res

    def train_deferred(
        self, max_iters: int | None = None
    ) -> tuple[TrainResult, Callable[[], None]]:
        """:meth:`train` without touching what readers of the map see: the decoder is trained
        as a copy and the touched features as a sub-table; the returned ``apply()`` writes both
        back (and bumps ``points.version``). Between the two the map answers queries as before
        the training, so another thread may track against it meanwhile (``train_latency`` 1);
        nothing else may change the map until ``apply()`` ran. ``train`` is this with
        ``apply()`` at once (the same numbers)."""
        with flush_denormals():
            return train_chunk(self, max_iters)

    def consolidate(self) -> None:
        """Take the diagonal Fisher of the decoder on the samples learned since the last call
        (call when the local frame is closed) and anchor EWC at the current weights."""
        if len(self._recent) == 0:
            return
        X, S = self._recent.points, self._recent.sdf
        idx, _ = self.points.knn(X)
        ok = idx[:, 0] >= 0
        X, S, idx = X[ok], S[ok], idx[ok]
        if X.shape[0] == 0 or not self.decoder.cfg.residual:
            return
        with torch.no_grad():
            inputs = self._decoder_inputs(X, *self._gather(idx))
        sigma = self.cfg.training.sigma
        fisher = diagonal_fisher(
            self.decoder,
            inputs,
            S,
            lambda out, y: bce_sdf_loss(out, y, sigma),
            method=self.cfg.training.fisher_method,
        )
        if self.cfg.training.ewc_normalize:
            mean = torch.cat([v.reshape(-1) for v in fisher.values()]).mean().clamp(min=1e-30)
            fisher = {k: v / mean for k, v in fisher.items()}
        self.ewc.consolidate(self.decoder, fisher)
        self._recent = ReplayPool(self.cfg.training.fisher_samples, self.device)

    def close(self) -> None:
        """The local frame is closed: :meth:`consolidate` (EWC), then hand a share of this
        frame's replay samples, with their decoder inputs from this frame's neural points, to
        :attr:`frame_replay`, which later frames sharing the decoder replay (with replay on)."""
        self.consolidate()
        tc = self.cfg.training
        fr = self.frame_replay
        if not (tc.use_replay and self.decoder.cfg.residual and len(self.replay)):
            return
        q = fr.share(1)
        if q == 0:
            return
        X, S, _ = self.replay.sample(q, self.generator)
        idx, _ = self.points.knn(X)
        ok = idx[:, 0] >= 0
        X, S, idx = X[ok], S[ok], idx[ok]
        if X.shape[0] == 0:
            return
        with torch.no_grad():
            inputs = self._decoder_inputs(X, *self._gather(idx))
        fr.add_frame(inputs, S, self.generator)

    # ------------------------------------------------------------------ decoding
    def _gather(self, idx: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Neighbour tables of (Q, k) global indices (-1 = none): positions, validity,
        features, colours, plane points and plane normals."""
        ic = idx.clamp(min=0)
        p = self.points
        q, n = p.planes()
        return p.positions[ic], idx >= 0, p.features[ic], p.colors[ic], q[ic], n[ic]

    def _decoder_inputs(self, x: torch.Tensor, *tables: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """:func:`~simn_sim.mapping.decoding.decoder_inputs` with this map's configs; ``tables``
        as returned by :meth:`_gather`."""
        return decoder_inputs(self.decoder.cfg, self.cfg.points, x, *tables)

    # ------------------------------------------------------------------ queries
    def query(
        self,
        points: np.ndarray | torch.Tensor,
        with_grad: bool = False,
        neighbors: torch.Tensor | None = None,
        tables: tuple[torch.Tensor, ...] | None = None,
    ) -> SdfQuery:
        """SDF (and gradient) at (N, 3) map-frame points, batched.

        Points without a neural point within ``search_radius`` are invalid: their SDF and
        gradient are NaN and ``valid`` is False. Returns numpy for numpy input, torch otherwise.
        ``neighbors``: (N, k) neural-point indices to use instead of a k-NN search (as
        returned by ``self.points.knn``; :class:`TrackingSdf` reuses them across iterations).
        ``tables``: with ``neighbors``, their neighbour tables as :meth:`_gather` returns them
        for all N rows, gathered at the map's current state (a row whose ``neighbors`` are all
        -1 is invalid whatever its tables hold).
        """
        is_np = isinstance(points, np.ndarray)
        x_all = _as_float_points(points).to(self.device, torch.float32)
        n = x_all.shape[0]
        sdf = torch.full((n,), float("nan"), device=self.device)
        grad = torch.full((n, 3), float("nan"), device=self.device) if with_grad else None
        valid = torch.zeros(n, dtype=torch.bool, device=self.device)
        step = self.cfg.points.query_chunk
        for s in range(0, n, step):
            x = x_all[s : s + step]
            if neighbors is None:
                idx, _ = self.points.knn(x)
            else:
                idx = neighbors[s : s + step]
            ok = idx[:, 0] >= 0
            if not ok.any():
                continue
            x, idx = x[ok], idx[ok]
            sl = torch.arange(s, s + ok.shape[0], device=self.device)[ok]
            valid[sl] = True
            if tables is None:
                nb = self._gather(idx)
            else:
                nb = tuple(t[s : s + step][ok] for t in tables)
            if with_grad:
                with torch.enable_grad():
                    xg = x.detach().clone().requires_grad_(True)
                    out = self.decoder(*self._decoder_inputs(xg, *nb))
                    (g,) = torch.autograd.grad(out.sum(), xg)
                sdf[sl] = out.detach()
                grad[sl] = g
            else:
                with torch.no_grad():
                    sdf[sl] = self.decoder(*self._decoder_inputs(x, *nb))
        if is_np:
            return SdfQuery(
                sdf.cpu().numpy(), None if grad is None else grad.cpu().numpy(), valid.cpu().numpy()
            )
        return SdfQuery(sdf, grad, valid)

    def sdf(self, points: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
        """(N,) SDF at map-frame points (NaN where no neural point is within reach)."""
        return self.query(points).sdf

    def sdf_and_grad(self, points: np.ndarray | torch.Tensor):
        """(N,) SDF and (N, 3) gradient d sdf / d p at map-frame points (NaN where invalid)."""
        q = self.query(points, with_grad=True)
        return q.sdf, q.grad

    def tracking_sdf(
        self, reuse_distance: float = 0.02, max_distance: float | None = None
    ) -> TrackingSdf:
        """``sdf_and_grad`` for registration that reuses each point's k neighbours across LM
        iterations and optionally has a tighter validity radius (see :class:`TrackingSdf`)."""
        return TrackingSdf(self, reuse_distance, max_distance)

    def feature_points(self) -> FeaturePoints:
        """Positions (map frame), features, colours and semantic labels of the neural points."""
        return self.points.snapshot()

    def nbytes(self) -> int:
        """Bytes held by the map's tensors (points, index, decoder, replay pool)."""
        n = self.points.nbytes()
        n += sum(p.numel() * p.element_size() for p in self.decoder.parameters())
        for pool in (self.replay, self._recent):
            n += sum(t.numel() * t.element_size() for t in (pool.points, pool.sdf, pool.kind))
        n += sum(t.numel() * t.element_size() for tri in self._pending for t in tri)
        return int(n)

    def extract_mesh(
        self,
        resolution: float = 0.02,
        bounds: np.ndarray | None = None,
        max_distance: float | None = None,
    ):
        """Zero level set as a triangle mesh (marching cubes); see :func:`mesh.extract_mesh`."""
        from simn_sim.mapping.mesh import extract_mesh

        return extract_mesh(self, resolution, bounds, max_distance)

    # ------------------------------------------------------------------ sibling maps
    def new_map(self, share_decoder: bool = True) -> ImplicitMap:
        """An empty map for a new local frame with the same config and generator.

        ``share_decoder``: the new map shares this map's decoder, EWC state and replay of
        closed frames (continual learning of one ``F_theta`` across frames; call :meth:`close`
        on this map when its frame closes). Otherwise it starts from a copy of the decoder with
        an empty EWC and replay (the frames no longer interact: nothing to forget)."""
        if share_decoder:
            return ImplicitMap(self.cfg, self.decoder, self.generator, self.ewc, self.frame_replay)
        return ImplicitMap(self.cfg, self.decoder.copy(), self.generator)

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict:
        return map_state(self)

    def save(self, path: str | Path) -> Path:
        """Write the map (config, decoder, points, EWC and replay state) to ``path``. Maps of
        local frames that share a decoder: :func:`save_frame_maps` writes it once."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), path)
        return path

    @classmethod
    def load(cls, path: str | Path, device: str | None = None) -> ImplicitMap:
        """Read a map written by :meth:`save`. Raises :class:`MapFileError` when the file is
        missing, corrupt, or not a simn-sim implicit map."""
        return load_map(cls, path, device)

    @classmethod
    def load_frames(cls, path: str | Path, device: str | None = None) -> dict[int, ImplicitMap]:
        """Read local-frame maps written by :func:`save_frame_maps` (``{frame id: map}``); maps
        that shared a decoder share it again (see :func:`load_frame_maps`)."""
        return load_frame_maps(cls, path, device)
