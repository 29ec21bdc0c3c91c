"""Obstacle-map cells judged against true footprints (simn_sim.eval.occupancy)."""

import numpy as np
import pytest

from simn_sim.eval.occupancy import cells_of, occupancy_scores

RES = 0.05
BOX = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # a 1 m square footprint


def _wall_points(x: float) -> np.ndarray:
    """A vertical wall face at x, y in [0.21, 0.79], z in [0.1, 0.9] (points every 1 cm)."""
    y, z = np.meshgrid(np.linspace(0.21, 0.79, 59), np.linspace(0.1, 0.9, 81))
    return np.stack([np.full(y.size, x), y.ravel(), z.ravel()], 1)


def test_surface_points_are_true_and_a_point_in_free_space_is_a_phantom():
    P = np.concatenate([_wall_points(1.0 + 1e-3), [[3.0, 3.0, 0.5]]])
    cells = cells_of(P, RES, (0.06, 1.0))
    # the face at x = 1.001 falls in the column of cells with x index 20 (1.00-1.05 m): y
    # 0.21-0.79 spans 12 cells (indices 4-15); plus the free-space point's cell
    assert len(cells) == 13
    s = occupancy_scores(cells, [BOX], RES, tol=0.05)
    # the face's cell centres are 0.025 m outside the square: within tol
    assert (s["cells"], s["true"], s["phantom"]) == (13, 12, 1)
    assert s["precision"] == pytest.approx(12 / 13)
    assert (20, 4) in s["true_set"] and (60, 60) not in s["true_set"]


def test_tolerance_is_the_distance_of_the_cell_centre_from_the_footprint():
    # a face at x = 1.16 falls in the cells spanning 1.15-1.20 m: centres 0.175 m from the square
    cells = cells_of(_wall_points(1.16), RES, (0.06, 1.0))
    assert occupancy_scores(cells, [BOX], RES, tol=0.17)["true"] == 0
    assert occupancy_scores(cells, [BOX], RES, tol=0.18)["true"] == len(cells)


def test_height_band_and_empty_maps():
    P = np.array([[0.5, 0.5, 0.03], [0.5, 0.5, 1.2]])  # below and above the band
    cells = cells_of(P, RES, (0.06, 1.0))
    assert cells.shape == (0, 2)
    s = occupancy_scores(cells, [BOX], RES, tol=0.05)
    assert s["cells"] == 0 and s["precision"] is None
    # no footprints at all: every cell is a phantom
    s = occupancy_scores(cells_of(_wall_points(1.0), RES, (0.06, 1.0)), [], RES, tol=0.05)
    assert s["true"] == 0 and s["phantom"] == s["cells"] > 0


def test_bad_input_is_named():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cells_of(np.zeros((4, 2)), RES, (0.0, 1.0))
    with pytest.raises(ValueError, match="NaN"):
        cells_of(np.array([[np.nan, 0.0, 0.5]]), RES, (0.0, 1.0))
    with pytest.raises(ValueError, match="resolution"):
        cells_of(np.zeros((1, 3)), 0.0, (0.0, 1.0))
    with pytest.raises(ValueError, match="z_band"):
        cells_of(np.zeros((1, 3)), RES, (1.0, 0.0))
    with pytest.raises(ValueError, match="tol"):
        occupancy_scores(np.zeros((1, 2), int), [BOX], RES, tol=-1.0)
    with pytest.raises(ValueError, match=r"\(M, 2\)"):
        occupancy_scores(np.zeros((3,), int), [BOX], RES, tol=0.1)
