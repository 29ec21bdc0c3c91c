"""Ray sampling for self-supervised SDF learning (paper: "Learning Spatial Surface Representation").

For a surface point ``p`` seen from camera centre ``e`` the samples lie on ``e + l (p - e)``:
in front of the surface (``l < 1``), behind it (``l > 1``), and on the plane through ``p``
perpendicular to the viewing ray within a radius ``r`` (plane-radius sampling). The label is
the signed distance along the ray, ``(1 - l) |p - e|``, positive in front of the surface; the
plane samples are labelled 0. Everything is vectorised in torch.
"""

from __future__ import annotations

import dataclasses

import torch

from simn_sim.mapping.config import SamplingConfig

SURFACE, FRONT, BEHIND = 0, 1, 2


@dataclasses.dataclass
class RaySamples:
    """points: (M, 3) float32 (frame of the inputs); sdf: (M,) signed-distance labels;
    kind: (M,) int8 (SURFACE / FRONT / BEHIND); ray: (M,) int64 index of the source point."""

    points: torch.Tensor
    sdf: torch.Tensor
    kind: torch.Tensor
    ray: torch.Tensor

    def __len__(self) -> int:
        return int(self.points.shape[0])


def perpendicular_basis(u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors (N, 3) orthogonal to the unit vectors ``u`` (N, 3) and to each other."""
    ux, uy, uz = u.unbind(1)
    # a = u x e_x where u is far from e_x, else u x e_y (explicit cross products)
    use_x = (ux.abs() < 0.9)[:, None]
    zero = torch.zeros_like(ux)
    a = torch.where(use_x, torch.stack([zero, uz, -uy], 1), torch.stack([-uz, zero, ux], 1))
    a = a / a.norm(dim=1, keepdim=True)
    b = torch.linalg.cross(u, a)
    return a, b


def sample_rays(
    points: torch.Tensor,
    origin: torch.Tensor,
    cfg: SamplingConfig,
    generator: torch.Generator | None = None,
    normals: torch.Tensor | None = None,
) -> RaySamples:
    """Samples around each surface point; see the module docstring.

    points: (N, 3) float32 surface points; origin: (3,) camera centre, same frame.
    normals: optional (N, 3) unit surface normals (NaN rows: unknown). Where a point has one,
    the ray samples are labelled with the distance to the point's tangent plane,
    ``(1 - l) |p - e| |cos theta|`` (theta between ray and normal) instead of the distance
    along the ray, which over-states the SDF by ``1 / cos theta`` on oblique surfaces, and
    the surface samples lie on the tangent plane instead of the plane perpendicular to the ray.
    Returns ``N * (n_surface + n_front + n_behind)`` samples, ray by ray: for each point its
    surface, then front, then behind samples.
    """
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {tuple(points.shape)}")
    dev, dt = points.device, points.dtype
    n = points.shape[0]
    ns, nf, nb = cfg.n_surface, cfg.n_front, cfg.n_behind
    per = ns + nf + nb
    e = origin.to(device=dev, dtype=dt).reshape(1, 3)
    d = points - e
    dist = d.norm(dim=1, keepdim=True)  # (N, 1)
    # one draw for everything: ns radii + ns angles + nf + nb ray parameters per point
    r = torch.rand((n, 2 * ns + nf + nb), generator=generator, device=dev, dtype=dt)
    out = torch.empty((n, per, 3), device=dev, dtype=dt)
    lab = torch.zeros((n, per), device=dev, dtype=dt)
    u = d / dist
    has_n = None
    if normals is not None:
        normals = normals.to(device=dev, dtype=dt)
        has_n = torch.isfinite(normals).all(1, keepdim=True)
        nrm = torch.where(has_n, normals, u)  # unknown: the ray (the plain labels)
    if ns > 0:
        a, b = perpendicular_basis(u if has_n is None else nrm)
        rho = cfg.surface_radius * torch.sqrt(r[:, :ns])
        phi = (2.0 * torch.pi) * r[:, ns : 2 * ns]
        out[:, :ns] = (
            points[:, None]
            + (rho * torch.cos(phi))[..., None] * a[:, None]
            + (rho * torch.sin(phi))[..., None] * b[:, None]
        )
    if nf + nb > 0:
        lo, hi = cfg.front_range
        blo, bhi = 1.0 + cfg.behind_min, 1.0 + cfg.behind_max
        lam = r[:, 2 * ns :]
        if nf:
            lam[:, :nf] = lo + (hi - lo) * lam[:, :nf]
        if nb:
            lam[:, nf:] = blo + (bhi - blo) * lam[:, nf:]
        out[:, ns:] = e + lam[..., None] * d[:, None]
        lab[:, ns:] = (1.0 - lam) * dist
        if has_n is not None:
            cos = (nrm * u).sum(1, keepdim=True).abs()
            lab[:, ns:] = lab[:, ns:] * cos
    kinds = [SURFACE] * ns + [FRONT] * nf + [BEHIND] * nb
    kind = torch.tensor(kinds, dtype=torch.int8, device=dev).repeat(n)
    ray = torch.arange(n, device=dev).repeat_interleave(per)
    return RaySamples(out.reshape(-1, 3), lab.reshape(-1), kind, ray)
