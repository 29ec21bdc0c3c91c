"""Transient obstacles (:mod:`simn_sim.world.transient`) on analytic depth images: a box that
appears where the camera saw the floor leaves after ``keep_views`` views unseen; the same box
seen without that free-space evidence stays."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.geometry.camera import Intrinsics
from simn_sim.world.obstacles import ObstacleConfig
from simn_sim.world.transient import TransientCells, TransientConfig

INTR = Intrinsics.from_fovy(80, 60, 90.0)
CAM_H = 1.0
BOX = (1.9, 2.3, -0.2, 0.2, 1.7)  # x0, x1, y0, y1, height (m): a person-sized box


def _T_wc(yaw: float, pitch: float = 0.0) -> np.ndarray:
    """A camera at (0, 0, CAM_H) looking along world heading ``yaw``, pitched down by
    ``pitch`` rad (OpenCV axes)."""
    c, s = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    T = np.eye(4)
    # camera x (right), y (down), z (forward) in the world
    T[:3, 0], T[:3, 1], T[:3, 2] = [s, -c, 0.0], [-sp * c, -sp * s, -cp], [cp * c, cp * s, -sp]
    T[2, 3] = CAM_H
    return T


def _depth(T_wc: np.ndarray, box: bool, intr: Intrinsics = INTR, box_xy=BOX) -> np.ndarray:
    """Exact depth (camera z, m) of the floor z = 0, walls at |x| = 4 and optionally BOX."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    d_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)], -1)
    d = d_cam @ T_wc[:3, :3].T  # world direction per unit of camera depth
    o = T_wc[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.full(u.shape, np.inf)
        t = np.where(d[..., 2] < 0, np.minimum(t, -o[2] / d[..., 2]), t)  # floor
        for wx in (4.0, -4.0):
            tw = (wx - o[0]) / d[..., 0]
            t = np.where(tw > 0, np.minimum(t, tw), t)
        if box:
            x0, x1, y0, y1, h = box_xy
            lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, h])
            t0, t1 = (lo - o) / d, (hi - o) / d
            tn = np.minimum(t0, t1).max(axis=-1)
            tf = np.maximum(t0, t1).min(axis=-1)
            t = np.where((tn <= tf) & (tn > 0), np.minimum(t, tn), t)
    return np.where(np.isfinite(t), t, 0.0)


def _box_face(box=BOX) -> np.ndarray:
    """Obstacle points on the box's face towards the camera, in the height band."""
    x0, _, y0, y1, _ = box
    y, z = np.meshgrid(np.linspace(y0, y1, 17), np.linspace(0.1, 1.0, 19))
    return np.column_stack([np.full(y.size, x0), y.ravel(), z.ravel()])


def _cells(keep: int = 5, grow_share: float = 0.4) -> TransientCells:
    cfg = TransientConfig(keep_views=keep, grow_share=grow_share)
    return TransientCells(cfg, (0.06, 1.0), 0.25)


def _view(tc: TransientCells, yaw: float, box: bool) -> None:
    T = _T_wc(yaw)
    seen = box and np.cos(yaw) > 0.5  # the face is in view (the camera looks along +x)
    pts = _box_face() if seen else np.zeros((0, 3))
    tc.observe(pts, T, np.zeros(2), _depth(T, box), INTR)


def test_free_space_test_matches_the_geometry():
    """Facing +x over an empty floor: every slab of a column 2 m ahead is seen free; no slab
    beyond the wall at x = 4 or behind the camera is; 0.35 m ahead only the top slab's centre
    (0.88 m) is within the image's 45 deg below the horizontal; the footprint is free."""
    tc = _cells()
    _view(tc, 0.0, box=False)
    ij = lambda x, y: tuple(np.floor(np.array([x, y]) / 0.1).astype(int) + tc.n // 2)  # noqa: E731
    np.testing.assert_allclose(tc.heights, [0.1775, 0.4125, 0.6475, 0.8825])
    assert (tc.free_at[ij(2.05, 0.05)] == 0).all()
    assert (tc.free_at[ij(3.35, -0.45)] == 0).all()  # within max_range, in view
    assert (tc.free_at[ij(4.25, 0.05)] < 0).all()  # behind the wall
    assert (tc.free_at[ij(-2.05, 0.05)] < 0).all()  # behind the camera
    assert list(tc.free_at[ij(0.35, 0.05)] == 0) == [False, False, False, True]
    assert (tc.free_at[ij(0.05, 0.05)] == 0).all()  # under the robot


def test_an_obstacle_that_appears_in_free_space_expires_unseen():
    """The box appears where view 0 saw the floor: its cells are transient. Turned away,
    its points stay in the models for ``keep_views`` views and are expired after; seen again
    before that, the count restarts; its space seen free after its last point, they are
    expired at once (carving misses some of a moving person's points)."""
    keep = 5
    tc = _cells(keep)
    _view(tc, 0.0, box=False)
    _view(tc, 0.0, box=True)  # view 1: the box appears
    face = _box_face()
    assert tc.n_appeared > 0 and not tc.expired(face).any()
    for k in range(keep):  # views 2..6, facing away
        _view(tc, np.pi, box=True)
        assert not tc.expired(face).any(), k
        assert not tc.expiring_now()
    _view(tc, np.pi, box=True)  # view 7: keep_views + 1 views since the box was seen
    assert tc.expired(face).all() and tc.expiring_now()
    _view(tc, 0.0, box=True)  # seen again: back in the models
    assert not tc.expired(face).any()
    for _ in range(keep + 1):
        _view(tc, np.pi, box=True)
    assert tc.expired(face).all()
    _view(tc, 0.0, box=True)  # seen again: back
    assert not tc.expired(face).any()
    _view(tc, 0.0, box=False)  # the box left and its space is seen free: its points go at once
    assert tc.expired(face).all() and tc.expiring_now()
    _view(tc, 0.0, box=True)  # and come back with the next view that sees it
    assert not tc.expired(face).any()


def test_an_obstacle_without_free_space_evidence_stays():
    """The same box seen at the first view (nothing seen free there before) never expires,
    and neither does one in a cell seen free longer than ``window`` views before."""
    tc = _cells()
    _view(tc, 0.0, box=True)
    for _ in range(20):
        _view(tc, np.pi, box=True)
    assert not tc.expired(_box_face()).any() and tc.n_appeared == 0
    late = TransientCells(TransientConfig(keep_views=5, window=3), (0.06, 1.0), 0.25)
    _view(late, 0.0, box=False)
    for _ in range(3):
        _view(late, np.pi, box=False)
    _view(late, 0.0, box=True)  # 4 views after the space was seen free
    for _ in range(10):
        _view(late, np.pi, box=True)
    assert not late.expired(_box_face()).any() and late.n_appeared == 0


def test_a_person_appears_in_view_of_the_d435i_mount():
    """The agent's camera (1.0 m up, pitched 24 deg down, 42.5 deg vertical field of view)
    sees nothing above 2.75 deg below the horizontal, so beyond 2.45 m the top slab's centre
    (0.88 m) is out of view. A person-sized box 3.0 m ahead, where view 0 saw the floor,
    appears in the three lower slabs, which view 0 saw free, and they expire unseen; the top
    slab, never seen free, does not appear by itself and its points stay without blob growth
    (``grow_share`` 0); with it, the top slab joins its appeared blob and expires too. (A test
    of the whole column, as before 2026-12-06, marked nothing free there: the person never
    appeared.)"""
    intr = Intrinsics.from_fovy(80, 60, 42.5)
    pitch = np.deg2rad(24.0)
    far = (3.0, 3.4, -0.2, 0.2, 1.7)
    keep = 3
    for grow in (0.0, 0.4):
        tc = _cells(keep, grow)
        gone = _person_at_3m(tc, intr, pitch, far, keep)
        low = _box_face(far)[:, 2] < 0.765  # the lower slabs (band 0.06-1.0, 0.235 m each)
        assert gone[low].all()
        assert gone[~low].all() if grow else not gone[~low].any()
        assert (tc.n_grown > 0) == (grow > 0)


def _person_at_3m(tc, intr, pitch, far, keep) -> np.ndarray:
    """Views of :func:`test_a_person_appears_in_view_of_the_d435i_mount`; returns which face
    points are expired at the end."""
    T0 = _T_wc(0.0, pitch)
    tc.observe(np.zeros((0, 3)), T0, np.zeros(2), _depth(T0, False, intr), intr)
    ij = lambda x, y: tuple(np.floor(np.array([x, y]) / 0.1).astype(int) + tc.n // 2)  # noqa: E731
    assert (tc.free_at[ij(2.05, 0.05)] == 0).all()
    assert list(tc.free_at[ij(3.05, 0.05)] == 0) == [True, True, True, False]
    face = _box_face(far)
    tc.observe(face, T0, np.zeros(2), _depth(T0, True, intr, far), intr)
    assert tc.n_appeared > 0 and not tc.expired(face).any()
    T1 = _T_wc(np.pi, pitch)
    for _ in range(keep + 1):  # turned away
        tc.observe(np.zeros((0, 3)), T1, np.zeros(2), _depth(T1, True, intr, far), intr)
    return tc.expired(face)


def test_a_static_edge_seen_past_does_not_appear():
    """A box there all along: the cell (1.9-2.0, 0.2-0.3) holds only its edge (y = 0.2), and
    its centre (1.95, 0.25) is seen through beside the box. A view whose edge points dropped
    out (depth noise) marks that cell free, and the next view's edge points land in it; the
    neighbour (1.95, 0.15) inside the box is never seen free, so nothing appears."""
    tc = _cells()
    T = _T_wc(0.0)
    face = _box_face()
    ij = tuple(np.floor(np.array([1.95, 0.25]) / 0.1).astype(int) + tc.n // 2)
    tc.observe(face[face[:, 1] < 0.19], T, np.zeros(2), _depth(T, True), INTR)
    assert (tc.free_at[ij] == 0).all()  # the edge cell's centre is seen through
    for _ in range(5):
        tc.observe(face, T, np.zeros(2), _depth(T, True), INTR)
    assert tc.n_appeared == 0 and not tc.expired(face).any()


def test_a_thin_leg_seen_past_does_not_appear():
    """A 4 cm leg (x 2.06-2.10, y 0.06-0.10), there all along, in the corner of the cell
    (2.0-2.1, 0.0-0.1): from the origin that cell's centre and those of its 8 neighbours are
    seen past the leg. View 0's leg points fell elsewhere (D435i noise moves them along their
    rays; edge dropout drops them), so the cell is seen free; view 1's points land in it. The
    slab rule alone takes it (``point_share`` 0); the per-point test projects them into view
    0, where they land on the leg itself, and nothing appears. A box that arrives where view
    0 saw the floor still appears with the test on (the tests above)."""
    intr = Intrinsics.from_fovy(640, 480, 60.0)
    leg = (2.06, 2.10, 0.06, 0.10, 1.0)
    y, z = np.meshgrid(np.linspace(0.065, 0.095, 4), np.linspace(0.1, 0.95, 12))
    face = np.column_stack([np.full(y.size, 2.06), y.ravel(), z.ravel()])
    T = _T_wc(0.0)
    depth = _depth(T, True, intr, leg)
    for share in (0.0, 0.5):
        tc = TransientCells(TransientConfig(keep_views=5, point_share=share), (0.06, 1.0), 0.25)
        tc.observe(np.zeros((0, 3)), T, np.zeros(2), depth, intr)
        ij = tuple(np.floor(np.array([2.05, 0.05]) / 0.1).astype(int) + tc.n // 2)
        assert (tc.free_at[ij] == 0).all()  # the leg's cell is seen free around the leg
        tc.observe(face, T, np.zeros(2), depth, intr)
        assert (tc.n_appeared > 0) == (share == 0.0), share
        for _ in range(6):  # turned away: what appeared expires
            T1 = _T_wc(np.pi)
            tc.observe(np.zeros((0, 3)), T1, np.zeros(2), _depth(T1, True, intr, leg), intr)
        assert tc.expired(face).all() == (share == 0.0)


def _sides(box, n: int = 17) -> np.ndarray:
    """Obstacle points on the box's two long sides (y = y0, y1), in the height band: what a
    depth camera leaves of a person walking along x, seen over several views."""
    x0, x1, y0, y1, _ = box
    x, z = np.meshgrid(np.linspace(x0, x1, n), np.linspace(0.1, 1.0, 10))
    return np.concatenate(
        [np.column_stack([x.ravel(), np.full(x.size, y), z.ravel()]) for y in (y0, y1)]
    )


def test_a_blob_beyond_the_free_space_test_expires_whole_by_growth():
    """A person-sized blob 3.0-3.8 m ahead: view 0 saw the floor free only to ``max_range``
    3.5 m, so the slabs nearer than about 3.4 m appear and those beyond never can (the
    corridor ghost of dyn-L2-003). Without growth the far part stays in the models after the
    robot turns away; with growth the whole blob expires."""
    blob = (3.0, 3.8, -0.2, 0.2, 1.7)
    pts = np.concatenate([_box_face(blob), _sides(blob)])
    keep = 3
    for grow in (0.0, 0.4):
        tc = _cells(keep, grow)
        T0, T1 = _T_wc(0.0), _T_wc(np.pi)
        tc.observe(np.zeros((0, 3)), T0, np.zeros(2), _depth(T0, False), INTR)
        tc.observe(pts, T0, np.zeros(2), _depth(T0, True, box_xy=blob), INTR)
        for _ in range(keep + 1):
            tc.observe(np.zeros((0, 3)), T1, np.zeros(2), _depth(T1, True, box_xy=blob), INTR)
        gone = tc.expired(pts)
        far = pts[:, 0] >= 3.6
        assert gone[~far].any() and far.any()
        if grow:
            assert gone.all() and tc.n_grown > 0
        else:
            assert not gone[far].any() and tc.n_grown == 0


def test_growth_does_not_take_a_static_box_beside_an_appearing_object():
    """A static box (there from view 0: never seen free) with a small object appearing right
    beside it: the two form one blob of which the object's appeared slabs are a small share.
    With ``grow_share`` 0.4 the box stays in the models after the robot turns away; with a
    share as low as 0.05 the box would be taken too (4 of the blob's 52 slabs appeared)."""
    box = (2.0, 2.4, -1.0, 0.0, 1.7)
    obj = (2.0, 2.2, 0.0, 0.3, 1.7)
    box_pts = _box_face(box)
    obj_pts = _box_face(obj)[_box_face(obj)[:, 1] > 0.05]
    keep = 3
    for grow, box_expires in ((0.4, False), (0.05, True)):
        tc = _cells(keep, grow)
        T0, T1 = _T_wc(0.0), _T_wc(np.pi)
        tc.observe(box_pts, T0, np.zeros(2), _depth(T0, True, box_xy=box), INTR)
        both = np.concatenate([box_pts, obj_pts])
        tc.observe(both, T0, np.zeros(2), _depth(T0, True, box_xy=box), INTR)
        assert tc.n_appeared > 0
        for _ in range(keep + 1):
            tc.observe(np.zeros((0, 3)), T1, np.zeros(2), _depth(T1, True, box_xy=box), INTR)
        assert tc.expired(box_pts).any() == box_expires, grow


def test_transient_config_and_input_are_checked():
    for field, bad in (
        ("keep_views", -1),
        ("window", 0),
        ("cell", 0.0),
        ("max_range", 0.0),
        ("grow_share", 1.5),
        ("point_share", -0.1),
        ("point_deg", 20.0),
    ):
        with pytest.raises(ConfigError, match=field):
            ObstacleConfig.from_dict({"transient": {field: bad}})
    tc = _cells()
    with pytest.raises(ValueError, match="does not match the intrinsics"):
        tc.observe(np.zeros((0, 3)), _T_wc(0.0), np.zeros(2), np.zeros((10, 10)), INTR)


def test_the_static_model_leaves_out_appeared_slabs():
    """ObstacleMap with transient cells: the box that appeared in space seen free is in the
    safety model but not in the static one (what the cost map prices instead of closing); a
    box there from the first view is in both."""
    from simn_sim.world.obstacles import ObstacleMap

    om = ObstacleMap(ObstacleConfig.from_dict({"transient": {"keep_views": 5}}))
    assert om.static_safety is None  # kept only when asked for
    om.keep_static()
    tc = om.transient
    T = _T_wc(0.0)
    tc.observe(np.zeros((0, 3)), T, np.zeros(2), _depth(T, False), INTR)
    face = _box_face()
    tc.observe(face, T, np.zeros(2), _depth(T, True), INTR)
    assert tc.appeared_at(face).all()
    om.add(face)
    at = np.array([[BOX[0] - 0.05, 0.0]])  # just in front of the face
    assert not om.safety.is_free(at)[0] and om.static_safety.is_free(at)[0]
    other = (1.9, 2.3, 1.0, 1.4, 1.7)  # seen at the first view of a fresh map: never appears
    om2 = ObstacleMap(ObstacleConfig.from_dict({"transient": {"keep_views": 5}}))
    om2.keep_static()
    pts = _box_face(other)
    om2.transient.observe(pts, T, np.zeros(2), _depth(T, True, box_xy=other), INTR)
    om2.add(pts)
    at2 = np.array([[other[0] - 0.05, 1.2]])
    assert not om2.safety.is_free(at2)[0] and not om2.static_safety.is_free(at2)[0]


def _frames_with(points: np.ndarray):
    """Real local frames (point-store kind) with one frame anchored at the world origin whose
    obstacle store holds ``points`` (world = anchor coordinates), stored as one view."""
    from simn_sim.perception.frame import Frame
    from simn_sim.semantics import OBSTACLE
    from simn_sim.slam.config import SlamConfig
    from simn_sim.slam.frames import LocalFrames

    frames = LocalFrames(SlamConfig(map_kind="points"))
    frames.open(np.eye(4), 0.0)
    n = len(points)
    view = Frame(
        points=points.astype(np.float32),
        normals=None,
        map_normals=None,
        colors=np.full((n, 3), 0.5, np.float32),
        pixels=np.zeros((n, 2), np.int64),
        depth=np.zeros((1, 1), np.float32),
        valid=np.zeros((1, 1), bool),
        stride=1,
        intrinsics=INTR,
        labels=np.full(n, OBSTACLE, np.int8),
    )
    frames.store(frames.current, view, np.eye(4))
    return frames


def _move_anchor(frames, dy: float) -> None:
    """What a pose-graph run does to frame 0: its anchor (and its points) move by ``dy``."""
    frames.topo.anchor(0)[1, 3] += dy
    frames.anchors_version += 1


# a person-sized box off the 0.1 m cell boundaries (the stores keep float32 points)
OFF_GRID = (1.93, 2.33, -0.17, 0.17, 1.7)


@pytest.mark.parametrize("follow", [True, False])
def test_an_appeared_obstacle_expires_after_the_pose_graph_moves_its_frame(follow):
    """The box appears in space seen free and is stored in a local frame; the pose graph then
    moves the frame's anchor 0.15 m sideways, carrying the points into slabs that never saw
    points arrive. Turned away for ``keep_views`` + 1 views, the models drop every one of them
    when each point is judged where it was observed (``follow_points``); judged where they are
    now, the points that moved into the never-occupied slabs stay for good (dyn-L5-000's
    standstill)."""
    from simn_sim.world.obstacles import ObstacleMap

    keep = 5
    om = ObstacleMap(
        ObstacleConfig.from_dict({"transient": {"keep_views": keep, "follow_points": follow}})
    )
    tc = om.transient
    T = _T_wc(0.0)
    tc.observe(np.zeros((0, 3)), T, np.zeros(2), _depth(T, False, box_xy=OFF_GRID), INTR)
    face = _box_face(OFF_GRID)
    tc.observe(face, T, np.zeros(2), _depth(T, True, box_xy=OFF_GRID), INTR)
    assert tc.appeared_at(face).all()
    frames = _frames_with(face)
    np.testing.assert_allclose(frames.obstacle_points_observed(), frames.obstacle_points_world())
    _move_anchor(frames, 0.15)
    moved = frames.obstacle_points_world()
    np.testing.assert_allclose(moved[:, 1] - frames.obstacle_points_observed()[:, 1], 0.15)
    om.keep_static()
    om.rebuild(frames)
    assert len(om.model_points(frames)) == len(moved)  # not expired yet
    assert not om.safety.is_free(moved[:, :2]).any()
    # the static model (the cost map's transient pricing) leaves out every appeared point when
    # judged where it was observed; judged where it is now, the moved-out ones stay in it
    in_static = ~om.static_safety.is_free(moved[:, :2])
    assert not in_static.any() if follow else in_static.any()
    for _ in range(keep + 1):
        Tb = _T_wc(np.pi)
        tc.observe(np.zeros((0, 3)), Tb, np.zeros(2), _depth(Tb, True, box_xy=OFF_GRID), INTR)
    left = om.model_points(frames)
    if follow:
        assert len(left) == 0
        om.rebuild(frames)
        assert om.safety.is_free(moved[:, :2]).all()
    else:
        # the face (y -0.17 to 0.17) occupied the cells from y -0.2 to 0.2; moved to y -0.02
        # to 0.32, the points from y 0.2 on are in cells that never saw a point arrive
        assert len(left) > 0 and (left[:, 1] >= 0.2).all()
        assert (moved[:, 1] >= 0.2).sum() == len(left)


def test_a_static_obstacle_stays_after_the_pose_graph_moves_its_frame():
    """A box seen from the first view (nothing seen free there before) never appears, so it
    stays in the models after its frame's anchor moves, judged where it was observed."""
    from simn_sim.world.obstacles import ObstacleMap

    om = ObstacleMap(
        ObstacleConfig.from_dict({"transient": {"keep_views": 5, "follow_points": True}})
    )
    T = _T_wc(0.0)
    face = _box_face(OFF_GRID)
    om.transient.observe(face, T, np.zeros(2), _depth(T, True, box_xy=OFF_GRID), INTR)
    frames = _frames_with(face)
    _move_anchor(frames, 0.15)
    for _ in range(8):
        Tb = _T_wc(np.pi)
        om.transient.observe(
            np.zeros((0, 3)), Tb, np.zeros(2), _depth(Tb, True, box_xy=OFF_GRID), INTR
        )
    om.rebuild(frames)
    assert len(om.model_points(frames)) == len(frames.obstacle_points_world())  # all stay
    assert not om.safety.is_free(frames.obstacle_points_world()[:, :2]).any()


def test_a_frames_first_view_is_restamped_where_its_moved_anchor_puts_it():
    """A revisit that moves a new frame's anchor right after its first view was stored: that
    view was seen from the moved anchor (the pipeline recomputes the camera pose through it),
    so its points are recorded as observed there."""
    frames = _frames_with(_box_face(OFF_GRID))
    _move_anchor(frames, -0.2)
    before = frames.obstacle_points_observed().copy()
    frames.restamp_observed(0)
    after = frames.obstacle_points_observed()
    np.testing.assert_allclose(after, frames.obstacle_points_world())
    np.testing.assert_allclose(before[:, 1] - after[:, 1], 0.2, atol=1e-6)
