"""Integration: label a frame's points and add them to the current local frame.

:func:`classify` labels each point floor / obstacle / overhead with the geometric classifier
(the floor is the base plane z = 0 of the estimated base pose, from ``T_base_cam``).
:func:`integrate` adds the frame to the local frame's surface store (the tracking model), its
obstacle / floor stores and, for a learned map, the map's training data, training it on the
frame's first observation (``open_train_iters``) and then every ``train_every``-th frame.
"""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.bounds import finite_rows
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.geometry.voxel import first_per_voxel
from simn_sim.mapping.mapper import ImplicitMap
from simn_sim.mapping.perception import EmptyFrameError
from simn_sim.perception.frame import Frame
from simn_sim.semantics import FloorClassifierConfig, classify_points
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import FrameState, LocalFrames
from simn_sim.slam.trainer import TrainWorker


def classify(
    frame: Frame, T_world_cam: np.ndarray, T_base_cam: np.ndarray, cfg: FloorClassifierConfig
) -> np.ndarray:
    """(N,) int8 labels of the frame's points (floor plane: the base plane at T_world_cam)."""
    if len(frame) == 0:
        return np.zeros(0, np.int8)
    T_world_base = T_world_cam @ inv_T(T_base_cam)
    n = T_world_base[:3, 2].copy()
    d = float(n @ T_world_base[:3, 3])
    R = T_world_cam[:3, :3]
    Pw = transform_points(T_world_cam, frame.points.astype(np.float64))
    Nw = frame.normals.astype(np.float64) @ R.T
    res = classify_points(Pw, Nw, cfg, plane=(n, d), ranges=frame.points[:, 2])
    return res.labels.astype(np.int8)


def integrate(
    frames: LocalFrames,
    st: FrameState,
    frame: Frame,
    T_anchor_cam: np.ndarray,
    cfg: SlamConfig,
    trainer: TrainWorker | None = None,
    keep: np.ndarray | None = None,
) -> bool:
    """Add a labelled ``frame`` (camera pose ``T_anchor_cam`` in ``st``'s anchor) to local frame
    ``st``. Returns False when the learned map rejected the frame as empty (counted by the
    caller), True otherwise. With a ``trainer`` the training runs on its worker thread and the
    bookkeeping after it (trained count, node refresh) when it is joined. ``keep``: (N,) bool,
    the points that go into the maps registration reads (surface store, learned map); the
    obstacle and floor stores take all of them (None: all everywhere)."""
    st.n_obs += 1
    if len(frame) == 0:
        return True
    frames.store(st, frame, T_anchor_cam)
    if keep is not None:
        frame = frame.select(keep)
    pts = frame.points
    ok = finite_rows(frame.normals)
    if ok.any():
        P, N = pts[ok], frame.normals[ok]
        idx = first_per_voxel(P, cfg.surface_voxel, order="key")
        st.surface.surface.add(
            transform_points(T_anchor_cam, P[idx].astype(np.float64)),
            (N[idx].astype(np.float64) @ T_anchor_cam[:3, :3].T).astype(np.float32),
        )
    topo, fid = frames.topo, st.frame.frame_id
    if not isinstance(st.frame.map, ImplicitMap):
        if st.n_obs in (1, 2, 4, 8) or st.n_obs % 10 == 0:
            topo.refresh(fid)
        return True
    m: ImplicitMap = st.frame.map
    if st.n_trained == 0:
        train_iters = cfg.open_train_iters
    elif st.n_obs % cfg.train_every == 0:
        train_iters = cfg.train_iters
    else:
        train_iters = 0
    try:
        m.integrate_frame(
            pts,
            T_anchor_cam,
            frame.colors,
            frame.labels.astype(np.int16),
            False,
            normals=frame.map_normals,
        )
    except EmptyFrameError:
        return False
    if train_iters:

        def trained(out, st=st, fid=fid) -> None:
            _res, apply = out
            apply()  # the trained decoder and features, visible to readers from here on
            st.n_trained += 1
            if st.n_trained in (1, 2, 4) or st.n_trained % 8 == 0:
                topo.refresh(fid)

        if trainer is None:
            trained(m.train_deferred(train_iters))
        else:
            trainer.submit(lambda: m.train_deferred(train_iters), trained)
    return True
