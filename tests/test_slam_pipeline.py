"""SimnSlam on a short simulated sequence (recorded into a tmp dir at 160x120)."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from simn_sim.eval.trajectory import ate_rpe  # noqa: E402
from simn_sim.io.tum import read_tum  # noqa: E402
from simn_sim.semantics import OBSTACLE  # noqa: E402
from simn_sim.slam import SimnSlam, SlamConfig  # noqa: E402
from simn_sim.slam.record import read_base, record_sequence  # noqa: E402


@pytest.fixture(scope="module")
def desk(tmp_path_factory):
    out = tmp_path_factory.mktemp("slam") / "desk"
    record_sequence(out, "desk", width=160, height=120, frames=30)
    return out


def _run(folder, cfg, n=None):
    seq = read_tum(folder)
    slam = SimnSlam(cfg, seq.intrinsics, read_base(folder))
    outs, gt = [], []
    for k, fr in enumerate(seq):
        if n is not None and k >= n:
            break
        outs.append(slam.process(fr.timestamp, fr.rgb, fr.depth))
        gt.append((fr.timestamp, fr.T_world_cam))
    return slam, outs, gt


def test_desk_ate_points_map(desk):
    # Target (DESIGN/issue): ATE <= 1 cm noise-free. Exact depth and a point-to-plane model
    # of the local frame give ~1-2 mm here (docs/slam.md); 1 cm leaves room for CPU/RNG noise
    # but not for a broken tracker (constant velocity alone drifts > 3 cm over this sequence).
    slam, outs, gt = _run(desk, SlamConfig(map_kind="points"))
    assert all(o.success for o in outs[1:]), [o.reason for o in outs if not o.success]
    m = ate_rpe(slam.trajectory(), gt)
    assert m["ate_rmse_m"] < 0.01, m
    # obstacles near the robot: within the depth range of the camera path
    obst = slam.obstacle_points_world()
    assert len(obst) > 50
    cam = np.array([T[:3, 3] for _, T in slam.trajectory()])
    d = np.linalg.norm(obst[:, None, :2] - cam[None, :, :2], axis=2).min(axis=1)
    # depth is along the optical axis: the range at the image corner is ~1.2x larger
    assert d.max() < 1.25 * slam.cfg.perception.max_depth
    assert (outs[-1].labels == OBSTACLE).sum() == len(outs[-1].obstacle_points_world)


def test_local_frames_open_and_arcs(desk):
    cfg = SlamConfig(map_kind="points", trigger={"max_travel_m": 0.15, "max_rotation_deg": 10.0})
    slam, outs, _ = _run(desk, cfg)
    assert slam.stats()["local_frames"] >= 3
    assert outs[0].new_local_frame
    assert sum(o.new_local_frame for o in outs) == slam.stats()["local_frames"]
    ids = [o.frame_id for o in outs]
    assert ids == sorted(ids)
    arcs = slam.topo.arcs("odom")
    assert len(arcs) == slam.stats()["local_frames"] - 1
    # an anchor is the camera pose at the frame's first observation
    first = {o.frame_id: o for o in reversed(outs)}
    for fid, o in first.items():
        np.testing.assert_allclose(slam.topo.anchor(fid), o.T_world_cam, atol=1e-9)


def test_lost_track_falls_back_to_prior(desk):
    seq = read_tum(desk)
    slam = SimnSlam(SlamConfig(map_kind="points"), seq.intrinsics, read_base(desk))
    f0, f1, f2 = seq[0], seq[1], seq[2]
    slam.process(f0.timestamp, f0.rgb, f0.depth)
    slam.process(f1.timestamp, f1.rgb, f1.depth)
    blank = np.zeros_like(f2.depth)
    out = slam.process(f2.timestamp, f2.rgb, blank)  # nothing valid: no exception
    assert not out.success and "points" in out.reason
    np.testing.assert_allclose(out.T_world_cam, out.prior)
    # garbage depth (random) must not raise either
    rng = np.random.default_rng(0)
    f3 = seq[3]
    junk = rng.uniform(0.3, 5.0, f3.depth.shape).astype(np.float32)
    out = slam.process(f3.timestamp, f3.rgb, junk)
    assert isinstance(out.success, bool)
    with pytest.raises(ValueError):
        slam.process(f3.timestamp, f3.rgb, f3.depth)  # timestamps must increase


def test_external_prior_defines_world_and_increments(desk):
    seq = read_tum(desk)
    slam = SimnSlam(SlamConfig(map_kind="points"), seq.intrinsics, read_base(desk))
    offset = np.eye(4)
    offset[:3, 3] = [5.0, -2.0, 0.0]
    est, gt = [], []
    for k in range(10):
        fr = seq[k]
        prior = offset @ fr.T_world_cam
        prior[:3, 3] += 0.01 * k  # a drifting prior: only its increments are used
        out = slam.process(fr.timestamp, fr.rgb, fr.depth, prior)
        est.append(out.T_world_cam)
        gt.append(offset @ fr.T_world_cam)
    np.testing.assert_allclose(est[0], gt[0], atol=1e-9)
    err = max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(est, gt, strict=True))
    # registration removed the 1 cm/frame prior drift. The residual (max 8.5 mm with the kernel
    # point SDF, 10.2 mm with the nearest-point one) is not the prior fusion or the gate
    # (fuse_prior=False: 10.6 mm, gate_sigmas=0: unchanged) but the registration stopping
    # short of a 17 mm start offset in frames 2-4, which the map then keeps (docs/slam.md)
    assert err < 0.01


def test_implicit_map_path_runs(desk):
    cfg = SlamConfig(map_kind="implicit", track_sdf="implicit", open_train_iters=20, train_iters=5)
    slam, outs, _ = _run(desk, cfg, n=4)
    fp = slam.topo.frame(0).map.feature_points()
    assert len(fp.positions) > 100
    assert outs[1].tracked_against == 0
    assert all(np.isfinite(o.T_world_cam).all() for o in outs)


def test_learned_map_tracking_preset_meets_the_desk_target(desk):
    # SlamConfig.for_learned_tracking(): every frame registered against the local frame's
    # learned map (geometric prior + learned residual, docs/mapping.md). Target: ATE <= 1 cm
    # noise-free (measured 1.7 mm on the 320x240 desk, 1.61 cm with D435i noise; the plain
    # learned decoder gave 3.5 cm)
    cfg = SlamConfig.for_learned_tracking()
    assert cfg.track_sdf == "implicit" and cfg.mapper.decoder.geometric_prior
    assert cfg.mapper.training.residual_weight > 0 and cfg.mapper.decoder.residual
    slam, outs, gt = _run(desk, cfg)
    assert all(o.success for o in outs[1:]), [o.reason for o in outs if not o.success]
    assert all(o.tracked_against is not None for o in outs[1:])
    m = ate_rpe(slam.trajectory(), gt)
    assert m["ate_rmse_m"] < 0.01, m
    fmap = slam.topo.frame(0).map
    assert fmap.n_trainings > 0  # the residual was trained, not only the prior


def test_yaml_preset_selects_learned_tracking(tmp_path):
    from simn_sim.config import ConfigError
    from simn_sim.slam.presets import load_slam_config

    f = tmp_path / "slam.yaml"
    f.write_text("preset: learned_tracking\ntrack_max_depth: 3.0\nmapper: {seed: 5}\n")
    cfg = load_slam_config(f)
    assert cfg.track_sdf == "implicit" and cfg.track_max_depth == 3.0
    assert cfg.mapper.decoder.geometric_prior and cfg.mapper.seed == 5
    assert load_slam_config(None).track_sdf == "points"  # the plain SlamConfig defaults
    # simn-sim slam's default: the learned map; a file without a preset changes that one,
    # 'point_tracking' names the plain defaults
    assert load_slam_config(None, default_preset="learned_tracking").track_sdf == "implicit"
    f.write_text("track_max_depth: 3.0\n")
    cfg = load_slam_config(f, default_preset="learned_tracking")
    assert cfg.track_sdf == "implicit" and cfg.track_max_depth == 3.0
    f.write_text("preset: point_tracking\ntrack_max_depth: 3.0\n")
    cfg = load_slam_config(f, default_preset="learned_tracking")
    assert cfg == SlamConfig(track_max_depth=3.0)
    # a nested mapping changes only the keys it names, at every depth: the preset's decoder
    # (geometric prior, normal gate) and points (Gaussian weights) survive one changed key
    f.write_text(
        "preset: learned_tracking\n"
        "mapper: {decoder: {residual: false}, points: {voxel_size: 0.02}}\n"
    )
    cfg = load_slam_config(f)
    d, pts = cfg.mapper.decoder, cfg.mapper.points
    assert not d.residual and d.geometric_prior and d.prior_normal_gate_deg == 60.0
    assert pts.voxel_size == 0.02 and pts.weighting == "gaussian"
    f.write_text("preset: nope\n")
    with pytest.raises(ConfigError, match="preset"):
        load_slam_config(f)


def _synthetic_view(box: bool):
    """160x120 depth: a wall 3 m ahead, optionally a box face 1.5 m ahead in the centre."""
    depth = np.full((120, 160), 3.0, np.float32)
    if box:
        depth[40:80, 60:100] = 1.5
    rgb = np.full((120, 160, 3), 128, np.uint8)
    return rgb, depth


def test_free_space_carving_removes_stale_obstacles():
    from simn_sim.geometry.camera import Intrinsics

    intr = Intrinsics(160, 120, 150.0, 150.0, 79.5, 59.5)
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical z = base x (forward)
    T_base_cam[2, 3] = 0.5
    for carve in (True, False):
        slam = SimnSlam(SlamConfig(map_kind="points", stores={"carve": carve}), intr, T_base_cam)
        prior = T_base_cam.copy()  # the robot stands still
        slam.process(0.0, *_synthetic_view(True), prior)
        near = np.linalg.norm(slam.obstacle_points_world()[:, :2], axis=1) < 2.0
        assert near.sum() > 20  # the box face is an obstacle
        slam.process(0.1, *_synthetic_view(False), prior)  # it has gone: seen through
        near = np.linalg.norm(slam.obstacle_points_world()[:, :2], axis=1) < 2.0
        if carve:
            assert near.sum() == 0
        else:
            assert near.sum() > 20
        # the wall behind stays
        assert (np.linalg.norm(slam.obstacle_points_world()[:, :2], axis=1) > 2.5).sum() > 20


def test_points_agent_preset_runs_cheaply(desk):
    cfg = SlamConfig.for_points_agent()
    assert cfg.map_kind == "points" and cfg.max_track_points <= 2500
    slam, outs, gt = _run(desk, cfg, n=10)
    assert all(o.success for o in outs[1:])
    assert ate_rpe(slam.trajectory(), gt)["ate_rmse_m"] < 0.01


def _tracker(**changes):
    """A point-store Tracker with no map, for the odometry prior and window logic."""
    from simn_sim.slam.frames import LocalFrames
    from simn_sim.slam.track import Tracker

    cfg = SlamConfig(map_kind="points", **changes)
    return Tracker(cfg, LocalFrames(cfg), np.random.default_rng(0))


def test_odometry_prior_grows_with_the_motion():
    """The odometry increment's sigma is the constant plus the per-unit growth times the motion
    (a 0.08 m step with a 0.05 rad turn: rot 0.1 deg + 0.02 x 0.13, trans 2 mm + 0.02 x 0.08
    m); without growth terms, the constant information; negative growth is a config error."""
    tr = _tracker(
        odom_prior_sigma_rot_deg=0.1,
        odom_prior_sigma_trans=0.002,
        odom_prior_sigma_rot_per_unit=0.02,
        odom_prior_sigma_trans_per_m=0.02,
    )
    tr.last_prior = np.eye(4)
    step = np.eye(4)
    c, s = np.cos(0.05), np.sin(0.05)
    step[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    step[:3, 3] = [0.08, 0.0, 0.0]
    sig = 1.0 / np.sqrt(np.diag(tr.odom_info(step)))
    np.testing.assert_allclose(sig[:3], np.radians(0.1) + 0.02 * 0.13, rtol=1e-9)
    np.testing.assert_allclose(sig[3:], 0.002 + 0.02 * 0.08, rtol=1e-9)
    tr0 = _tracker(odom_prior_sigma_rot_deg=0.1)
    tr0.last_prior = np.eye(4)
    sig0 = 1.0 / np.sqrt(np.diag(tr0.odom_info(step)))
    np.testing.assert_allclose(sig0, [np.radians(0.1)] * 3 + [0.005] * 3, rtol=1e-9)
    with pytest.raises(ValueError, match="odom_prior_sigma_trans_per_m"):
        SlamConfig(odom_prior_sigma_trans_per_m=-0.1)


def test_fusion_weighs_the_scaled_registration_covariance_against_the_prior():
    """Fused correction per tangent direction = info / (info + prior) x the registration's
    correction, info = 1 / (track_cov_scale x its variance): scaling the covariance by s moves
    the estimate towards the prediction exactly so; ``track_cov_scale_trans`` scales the
    translation block alone."""
    from types import SimpleNamespace

    from simn_sim.geometry.se3 import se3_exp
    from simn_sim.tracking.lie import se3_log

    delta = np.array([0.002, -0.001, 0.003, 0.01, -0.004, 0.006])
    var = np.array([1e-6, 2e-6, 1e-6, 4e-5, 1e-5, 2e-5])
    prior_info = np.diag(1.0 / np.array([1e-6] * 3 + [2.5e-5] * 3))
    pts = np.random.default_rng(0).uniform(-1, 1, (100, 3)) + [0, 0, 2]
    res = SimpleNamespace(covariance=np.diag(var), eig_ratio=1.0)
    # (rotation scale, translation scale): track_cov_scale_trans 0 takes the rotation's
    for s, st in ((1.0, 0.0), (30.0, 0.0), (30.0, 1000.0)):
        tr = _tracker(track_cov_scale=s, track_cov_scale_trans=st, gate_sigmas=0.0)
        T_pred = np.eye(4)
        fused = tr._fuse(pts, T_pred, se3_exp(delta), res, prior_info)
        info = 1.0 / (np.array([s] * 3 + [st or s] * 3) * var)
        expect = info / (info + np.diag(prior_info)) * delta
        np.testing.assert_allclose(se3_log(fused), expect, rtol=1e-6, atol=1e-12)


def test_learned_tracking_preset_verifies_revisits_on_the_surface_store():
    """The preset's revisit checks verify on the surface store, as the closed-loop agent's
    (``revisit_sdf: points``: 4 revisits of TUM fr1/rpy against 1 on the learned SDF;
    docs/slam.md); switched back to the learned SDF they take tracking's gradient-norm validity
    floor (the point store's 0.5 left 7-8 % of an observation without an SDF there)."""
    cfg = SlamConfig.for_learned_tracking()
    assert cfg.track_sdf == "implicit"
    assert cfg.revisit_sdf == "points" == SlamConfig.for_agent().revisit_sdf
    assert cfg.registration.grad_norm_min == cfg.track_registration.grad_norm_min < 0.5
    # a change of the preset keeps them apart only when asked
    c2 = SlamConfig.for_learned_tracking(registration={"grad_norm_min": 0.4})
    assert c2.registration.grad_norm_min == 0.4 and c2.track_registration.grad_norm_min == 0.3


def _base_tilt(T_plane_base):
    """(z, roll, pitch) of a base pose relative to the plane's base: m, rad, rad."""
    R = T_plane_base[:3, :3]
    return T_plane_base[2, 3], np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(np.clip(R[2, 0], -1, 1))


@pytest.mark.parametrize("on_plane", [False, True])
def test_planar_poses_and_anchors_stay_on_the_floor_plane(desk, on_plane):
    """``planar``: the recorded base drives on the flat floor (its true z, roll and pitch are
    those of the first frame); every estimate and every anchor keeps them exactly, x, y and
    yaw are still tracked to the noise-free target, and a tilted pose is projected without
    moving its x, y or yaw. ``planar_registration`` (``on_plane``): the same, registering on
    the plane."""
    from simn_sim.geometry.se3 import inv_T, make_T, planar_T, so3_exp, yaw_of

    T_bc = read_base(desk)
    cfg = SlamConfig(map_kind="points", planar=True, planar_registration=on_plane)
    slam, outs, gt = _run(desk, cfg)
    assert (slam.tracker.B_cam is not None) == on_plane
    T0b_true = gt[0][1] @ inv_T(T_bc)
    for _, T in gt:  # the ground truth is planar: the constraint is exact here
        z, r, p = _base_tilt(inv_T(T0b_true) @ T @ inv_T(T_bc))
        assert abs(z) < 1e-6 and abs(r) < 1e-6 and abs(p) < 1e-6
    T0b = outs[0].T_world_cam @ inv_T(T_bc)
    poses = [o.T_world_cam for o in outs] + [slam.topo.anchor(f) for f in slam.topo.frame_ids]
    for T in poses:
        z, r, p = _base_tilt(inv_T(T0b) @ T @ inv_T(T_bc))
        assert abs(z) < 1e-9 and abs(r) < 1e-9 and abs(p) < 1e-9, (z, r, p)
    assert ate_rpe(slam.trajectory(), gt)["ate_rmse_m"] < 0.01
    # the projection: 5 cm up and 2 deg of roll go, x, y and yaw stay
    flat = planar_T(0.4, -0.3, 0.7)
    tilted = flat @ make_T(so3_exp(np.array([np.radians(2.0), 0.0, 0.0])), np.array([0, 0, 0.05]))
    T_in = T0b @ tilted @ T_bc
    rel = inv_T(T0b) @ slam._planar(T_in) @ inv_T(T_bc)
    np.testing.assert_allclose(rel, flat, atol=1e-12)
    assert abs(yaw_of(rel) - 0.7) < 1e-12
    with pytest.raises(ValueError, match="planar needs T_base_cam"):
        SimnSlam(cfg, read_tum(desk).intrinsics, None)
    from simn_sim.config import ConfigError

    with pytest.raises(ConfigError, match="planar_registration"):
        SlamConfig(planar_registration=True)


@pytest.mark.parametrize("target", ["tracking", "points"])
def test_revisit_check_registers_against_the_chosen_map(desk, target):
    """``revisit_sdf``: a revisit check's registration, against the learned map (``tracking``)
    or the frame's surface store (``points``), brings a later observation perturbed by 4 cm and
    3 deg back to its tracked pose in the first frame (the desk is tracked to ~1 mm)."""
    from simn_sim.geometry.se3 import inv_T, pose_error, se3_exp

    cfg = SlamConfig.for_agent(revisit_sdf=target, train_async=False)
    slam, outs, gt = _run(desk, cfg, n=12)
    assert ate_rpe(slam.trajectory(), gt)["ate_rmse_m"] < 0.01
    fr = read_tum(desk)[11]
    frame = slam.perception(fr.rgb, fr.depth)
    pts = slam.tracker.track_points(frame.points, frame.normals)
    T_f_cam = inv_T(slam.topo.anchor(0)) @ outs[11].T_world_cam
    T_init = T_f_cam @ se3_exp(np.array([0.0, np.radians(3.0), 0.0, 0.03, 0.0, -0.027]))
    res = slam.revisits._loop_register(0, pts, T_init)
    assert res.success, res.reason
    dt, dr = pose_error(res.pose, T_f_cam)
    assert dt < 0.01 and np.degrees(dr) < 0.5, (dt, np.degrees(dr))
    # the surface store's SDF is built for the check only when it is the target
    assert (slam.frames.states[0].loop_sdf is not None) == (target == "points")


def _fwd(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z  # camera frame: forward is +z
    return T


def test_odometry_window_falls_back_when_tracking_slides_off_the_odometry():
    """Odometry steps 0.08 m forward (sigma 2 mm + 0.02 x 0.08 = 3.6 mm per frame); the
    tracked steps are 1 cm longer. After n sliding frames the window statistic is
    0.01 n / (3.6 mm sqrt(n)) = 2.78 sqrt(n): 4.81 at n = 3, 5.56 at n = 4, so the gate of 5
    fires at the 4th, and the pose is then the window's start moved by the odometry; the
    window restarts there, so it fires again 4 frames later. Frames tracked exactly along the
    odometry never fire."""
    from simn_sim.slam.track import TrackResult

    tr = _tracker(
        odom_prior_sigma_trans=0.002,
        odom_prior_sigma_trans_per_m=0.02,
        odom_window=10,
        odom_window_sigmas=5.0,
    )
    tr.start(0.0)
    tr.commit(0.0, np.eye(4), np.eye(4))
    prior, fired, stats = np.eye(4), [], []
    for k in range(1, 10):
        prior = prior @ _fwd(0.08)
        T_prev = tr.hist[-1][1]
        res = tr._check_window(TrackResult(T_prev @ _fwd(0.09), True, "ok", 5, 0, 0.01), prior)
        stats.append(tr.window_sigmas)
        if not res.success:
            fired.append(k)
            assert "sigma off the odometry over 4 frames" in res.reason
            # the window's start (3 frames back: 0.27 m tracked) moved by 4 odometry steps
            np.testing.assert_allclose(res.T_anchor_cam, T_prev @ _fwd(-0.27 + 0.32), atol=1e-9)
        tr.commit(float(k), res.T_anchor_cam, prior)
    n = np.arange(1, 5)
    np.testing.assert_allclose(stats[:4], 0.01 * n / (0.0036 * np.sqrt(n)), rtol=1e-6)
    assert fired == [4, 8]
    for k in range(10, 30):  # tracked exactly along the odometry
        prior = prior @ _fwd(0.08)
        res = tr._check_window(
            TrackResult(tr.hist[-1][1] @ _fwd(0.08), True, "ok", 5, 0, 0.01), prior
        )
        assert res.success
        n = k - 8  # frames in the window since the restart, frame 9's 1 cm among them
        expect = 0.01 / (0.0036 * np.sqrt(n)) if n <= 10 else 0.0
        assert abs(tr.window_sigmas - expect) < 1e-6, (k, tr.window_sigmas)
        tr.commit(float(k), res.T_anchor_cam, prior)
    with pytest.raises(ValueError, match="odom_window"):
        SlamConfig(odom_window=-1)
    with pytest.raises(ValueError, match="odom_window_sigmas"):
        SlamConfig(odom_window_sigmas=0.0)


def test_odometry_window_keeps_a_correct_registration(desk):
    """With the odometry exact (the ground-truth increments) the window test never overrules
    the registration on the desk sequence, and the ATE target holds."""
    seq = read_tum(desk)
    cfg = SlamConfig(map_kind="points", odom_window=10, odom_window_sigmas=5.0)
    slam = SimnSlam(cfg, seq.intrinsics, read_base(desk))
    gt = []
    for fr in seq:
        out = slam.process(fr.timestamp, fr.rgb, fr.depth, fr.T_world_cam)
        assert "odometry over" not in out.reason, out.reason
        gt.append((fr.timestamp, fr.T_world_cam))
    assert np.isfinite(slam.tracker.window_sigmas)
    assert ate_rpe(slam.trajectory(), gt)["ate_rmse_m"] < 0.01


def test_points_in_dynamic_space_stay_out_of_registration_and_its_maps():
    """A box face 1.5 m ahead appears in front of a wall 3 m ahead; the caller says the space
    within 2 m is dynamic (as the agent's transient cells do for a person): the face's points
    reach the obstacle store but not the surface store that tracking and the revisit checks
    register against, nor the registration points."""
    from simn_sim.geometry.camera import Intrinsics

    intr = Intrinsics(160, 120, 150.0, 150.0, 79.5, 59.5)
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical z = base x (forward)
    T_base_cam[2, 3] = 0.5

    def near(P: np.ndarray) -> np.ndarray:  # world points within 2 m of the camera (x-y)
        return np.linalg.norm(P[:, :2], axis=1) < 2.0

    runs = {}
    for dynamic in (None, near):
        slam = SimnSlam(SlamConfig(map_kind="points", stores={"carve": False}), intr, T_base_cam)
        slam.process(0.0, *_synthetic_view(False), T_base_cam, dynamic)
        out = slam.process(0.1, *_synthetic_view(True), T_base_cam, dynamic)
        st = slam.frames.states[out.frame_id]
        A = slam.frames.topo.anchor(out.frame_id)
        surf = st.surface.surface.points @ A[:3, :3].T + A[:3, 3]
        obst = slam.obstacle_points_world()
        runs[dynamic is not None] = (
            int(near(surf).sum()),
            int(near(obst).sum()),
            out.n_track_points,
            slam.stats()["dynamic_points"],
        )
    surf_near, obst_near, n_track, n_dyn = runs[True]
    surf_near0, obst_near0, n_track0, n_dyn0 = runs[False]
    assert surf_near0 > 20 and n_dyn0 == 0  # without the mask the face is in the surface store
    assert surf_near == 0  # with it, none of the face
    assert obst_near == obst_near0 > 20  # the obstacle store keeps all of it
    assert n_dyn > 20 and n_track < n_track0
    # the mask must be one bool per point
    slam = SimnSlam(SlamConfig(map_kind="points"), intr, T_base_cam)
    slam.process(0.0, *_synthetic_view(False), T_base_cam)
    with pytest.raises(ValueError, match="dynamic must give"):
        slam.process(0.1, *_synthetic_view(True), T_base_cam, lambda P: np.ones(3, bool))


def test_wall_heading_turns_the_new_anchor_and_keeps_the_tracked_motion(desk):
    """``heading``: a residual of -3 deg (gain 0.5) at the first frame change turns the new
    anchor's base by exactly 1.5 deg about its own vertical (x, y kept) against the same run without
    it, and the tracker's history is re-expressed, so the tracked motion into the new frame is
    unchanged. With its real residuals on ideal depth, a reference is set, no pool is beyond
    the gate and the trajectory keeps its noise-free accuracy."""
    from simn_sim.geometry.se3 import inv_T, yaw_of

    T_bc = read_base(desk)
    trig = {"max_travel_m": 0.15, "max_rotation_deg": 10.0}
    base_cfg = SlamConfig(map_kind="points", planar=True, trigger=trig)
    seq = read_tum(desk)

    def first_change(cfg, fixed=None):
        slam = SimnSlam(cfg, seq.intrinsics, T_bc)
        if fixed is not None:
            slam.heading.residual = lambda R: fixed
        for fr in seq:
            out = slam.process(fr.timestamp, fr.rgb, fr.depth)
            if out.frame_id == 1:
                (_, T0), (_, T1) = slam.tracker.hist
                return slam, out, inv_T(T0) @ T1
        raise AssertionError("no second local frame")

    s0, o0, inc0 = first_change(base_cfg)
    cfg = base_cfg.replace(heading=base_cfg.heading.replace(enabled=True))
    s1, o1, inc1 = first_change(cfg, fixed=-3.0)
    plane = s0._T_plane
    b0 = inv_T(plane) @ o0.T_world_cam @ inv_T(T_bc)
    b1 = inv_T(plane) @ o1.T_world_cam @ inv_T(T_bc)
    np.testing.assert_allclose(b1[:2, 3], b0[:2, 3], atol=1e-9)
    assert np.degrees(yaw_of(b1) - yaw_of(b0)) == pytest.approx(1.5, abs=1e-9)
    np.testing.assert_allclose(s1.topo.anchor(1), o1.T_world_cam, atol=1e-12)
    np.testing.assert_allclose(inc1, inc0, atol=1e-9)  # the same motion, other coordinates
    # the odometry arc into the new frame carries the correction
    arc = inv_T(s1.topo.anchor(0)) @ s1.topo.anchor(1)
    arc0 = inv_T(s0.topo.anchor(0)) @ s0.topo.anchor(1)
    assert not np.allclose(arc, arc0, atol=1e-4)

    cfg = cfg.replace(heading=cfg.heading.replace(prior_sigma_deg=1.0))
    slam, outs, gt = _run(desk, cfg)
    h = slam.stats()["heading"]
    assert h["reference_deg"] is not None and h["pools"] >= 2 and h["gated"] == 0, h
    # each accepted residual put a heading prior on its closed frame for the pose graph
    assert h["priors"] == h["corrections"] >= 1, h
    for T, info in slam.topo.anchor_priors.values():
        assert np.linalg.eigvalsh(info).max() > 1e6 * np.linalg.eigvalsh(info).min()
        up = T[:3, :3].T @ slam._T_plane[:3, 2]  # the plane's vertical in the anchor's axes
        assert up @ info[:3, :3] @ up == pytest.approx(np.linalg.eigvalsh(info).max(), rel=1e-6)
    assert abs(slam.heading.last_residual_deg) < 0.5 or np.isnan(slam.heading.last_residual_deg)
    assert ate_rpe(slam.trajectory(), gt)["ate_rmse_m"] < 0.01
