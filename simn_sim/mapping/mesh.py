"""Zero level set of a map as a triangle mesh (marching cubes, scikit-image), and rerun logging."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy import ndimage
from skimage import measure

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap


@dataclasses.dataclass(frozen=True)
class Mesh:
    """vertices (V, 3) float32 in map coordinates, faces (F, 3) int32, normals (V, 3) float32."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


def extract_mesh(
    imap: ImplicitMap,
    resolution: float = 0.02,
    bounds: np.ndarray | None = None,
    max_distance: float | None = None,
) -> Mesh:
    """Marching cubes on the SDF sampled on a grid of ``resolution`` metres.

    Only grid nodes within ``max_distance`` of a neural point are used (default: 1.5 neural
    voxels; the surface passes through the points, and farther away the field is an
    extrapolation that can cross zero spuriously). ``bounds`` (2, 3) [min, max] defaults to
    the points' bounding box plus that distance. Returns an empty mesh when there is no zero
    crossing.
    """
    if resolution <= 0:
        raise ValueError(f"resolution must be > 0, got {resolution}")
    pos = imap.points.positions.cpu().numpy()
    empty = Mesh(
        np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros((0, 3), np.float32)
    )
    if pos.shape[0] == 0:
        return empty
    r = 1.5 * imap.cfg.points.voxel_size if max_distance is None else float(max_distance)
    r = min(r, imap.cfg.points.search_radius)
    if bounds is None:
        bounds = np.stack([pos.min(0) - r, pos.max(0) + r])
    lo, hi = np.asarray(bounds, np.float64)
    shape = np.maximum(np.ceil((hi - lo) / resolution).astype(int) + 1, 2)
    # grid nodes near neural points: occupancy dilated by the search radius
    occ = np.zeros(shape, bool)
    ijk = np.round((pos - lo) / resolution).astype(int)
    inside = np.all((ijk >= 0) & (ijk < shape), axis=1)
    occ[tuple(ijk[inside].T)] = True
    rad = max(int(np.ceil(r / resolution)), 1)
    g = np.arange(-rad, rad + 1)
    ball = (g[:, None, None] ** 2 + g[None, :, None] ** 2 + g[None, None, :] ** 2) <= rad**2
    near = ndimage.binary_dilation(occ, structure=ball)
    nodes = np.argwhere(near)
    xyz = (lo + nodes * resolution).astype(np.float32)
    _, d2 = imap.points.knn(torch.from_numpy(xyz))
    close = (d2[:, 0] <= r * r).cpu().numpy()
    nodes, xyz = nodes[close], xyz[close]
    q = imap.query(xyz)
    vol = np.full(shape, np.nan, np.float32)
    vol[tuple(nodes.T)] = q.sdf
    mask = np.isfinite(vol)
    if not mask.any() or np.nanmin(vol) > 0 or np.nanmax(vol) < 0:
        return empty
    fill = np.where(mask, vol, np.float32(np.nanmax(vol)))
    try:
        v, f, n, _ = measure.marching_cubes(fill, level=0.0, spacing=(resolution,) * 3, mask=mask)
    except (ValueError, RuntimeError):
        return empty
    v = (v + lo).astype(np.float32)
    # Faces at the edge of the mask interpolate towards the fill value: their vertices are not
    # zeros of the field. Keep faces whose three vertices are (near) zeros of the map's SDF.
    sv = imap.sdf(v)
    good_v = np.isfinite(sv) & (np.abs(sv) <= 0.5 * resolution)
    f = f[good_v[f].all(axis=1)]
    used = np.unique(f)
    remap = np.full(len(v), -1, np.int64)
    remap[used] = np.arange(len(used))
    return Mesh(v[used], remap[f].astype(np.int32), n[used].astype(np.float32))


def log_mesh(entity_path: str, mesh: Mesh, color: tuple[int, int, int] = (180, 180, 200)) -> None:
    """Log ``mesh`` to the active rerun recording as a ``Mesh3D``."""
    import rerun as rr

    rr.log(
        entity_path,
        rr.Mesh3D(
            vertex_positions=mesh.vertices,
            triangle_indices=mesh.faces,
            vertex_normals=mesh.normals,
            albedo_factor=np.array([*color, 255], np.uint8),
        ),
    )
