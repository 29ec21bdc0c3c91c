"""column_bounds and finite_rows give exactly what numpy's axis reductions give."""

import numpy as np
import pytest

from simn_sim.geometry.bounds import column_bounds, finite_rows


@pytest.mark.parametrize("dtype", [np.int64, np.float32, np.float64])
def test_column_bounds_equal_numpy_axis0_reductions(dtype):
    rng = np.random.default_rng(3)
    a = (rng.normal(size=(1000, 3)) * 100).astype(dtype)
    lo, hi = column_bounds(a)
    assert lo.dtype == a.dtype and hi.dtype == a.dtype
    np.testing.assert_array_equal(lo, a.min(axis=0))
    np.testing.assert_array_equal(hi, a.max(axis=0))
    # a strided view (the x-y columns of (N, 3) points)
    lo2, hi2 = column_bounds(a[:, :2])
    np.testing.assert_array_equal(lo2, a[:, :2].min(axis=0))
    np.testing.assert_array_equal(hi2, a[:, :2].max(axis=0))


def test_column_bounds_propagate_nan_and_reject_bad_shapes():
    a = np.array([[0.0, 1.0], [np.nan, -2.0], [3.0, 5.0]])
    lo, hi = column_bounds(a)
    assert np.isnan(lo[0]) and np.isnan(hi[0])
    assert (lo[1], hi[1]) == (-2.0, 5.0)
    with pytest.raises(ValueError, match="non-empty"):
        column_bounds(np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"\(N, D\)"):
        column_bounds(np.zeros(5))


def test_finite_rows_equals_isfinite_all_over_the_last_axis():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(500, 3)).astype(np.float32)
    a[rng.random(a.shape) < 0.1] = np.nan
    a[3, 1] = np.inf
    for x in (a, a.reshape(50, 10, 3), a[:, :2], a[:, :1]):
        got = finite_rows(x)
        np.testing.assert_array_equal(got, np.isfinite(x).all(axis=-1))
        assert got.any() and not got.all()


def test_on_plane_keeps_x_y_yaw_and_drops_the_rest() -> None:
    """``se3.on_plane``: a base 4 cm above a tilted plane, rolled and pitched, lands on the
    plane with its in-plane position and yaw kept; ``dyaw`` adds to the yaw exactly."""
    from simn_sim.geometry.se3 import inv_T, make_T, on_plane, planar_T, so3_exp, yaw_of

    T_plane = make_T(so3_exp(np.array([0.02, -0.01, 0.7])), np.array([1.0, -2.0, 0.1]))
    T_base_cam = make_T(so3_exp(np.array([-1.9, 0.0, -1.5])), np.array([0.1, 0.0, 1.0]))
    rel = make_T(so3_exp(np.array([0.05, -0.03, 0.4])), np.array([2.0, 3.0, 0.04]))
    T_world_cam = T_plane @ rel @ T_base_cam
    for dyaw in (0.0, 0.3):
        out = inv_T(T_plane) @ on_plane(T_plane, T_world_cam, T_base_cam, dyaw) @ inv_T(T_base_cam)
        assert np.allclose(out, planar_T(2.0, 3.0, yaw_of(rel) + dyaw), atol=1e-12)
