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
