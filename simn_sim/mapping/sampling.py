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
    helper = torch.zeros_like(u)
    use_x = u[:, 0].abs() < 0.9
    helper[use_x, 0] = 1.0
    helper[~use_x, 1] = 1.0
    a = torch.linalg.cross(u, helper)
    a = a / a.norm(dim=1, keepdim=True)
    b = torch.linalg.cross(u, a)
    return a, b


def sample_rays(
    points: torch.Tensor,
    origin: torch.Tensor,
    cfg: SamplingConfig,
    generator: torch.Generator | None = None,
) -> RaySamples:
    """Samples around each surface point; see the module docstring.

    points: (N, 3) float32 surface points; origin: (3,) camera centre, same frame.
    Returns ``N * (n_surface + n_front + n_behind)`` samples grouped by kind.
    """
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {tuple(points.shape)}")
    dev, dt = points.device, points.dtype
    n = points.shape[0]
    e = origin.to(device=dev, dtype=dt).reshape(1, 3)
    d = points - e
    dist = d.norm(dim=1, keepdim=True)  # (N, 1)

    def uniform(m: int, lo: float, hi: float) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand((n, m), generator=generator, device=dev, dtype=dt)

    out_p, out_s, out_k, out_r = [], [], [], []
    idx = torch.arange(n, device=dev)

    def emit(p: torch.Tensor, s: torch.Tensor, kind: int) -> None:
        m = p.shape[1]
        out_p.append(p.reshape(-1, 3))
        out_s.append(s.reshape(-1))
        out_k.append(torch.full((n * m,), kind, dtype=torch.int8, device=dev))
        out_r.append(idx.repeat_interleave(m))

    if cfg.n_surface > 0:
        u = d / dist
        a, b = perpendicular_basis(u)
        rho = cfg.surface_radius * torch.sqrt(uniform(cfg.n_surface, 0.0, 1.0))
        phi = uniform(cfg.n_surface, 0.0, 2.0 * torch.pi)
        off = (rho * torch.cos(phi))[..., None] * a[:, None] + (rho * torch.sin(phi))[
            ..., None
        ] * b[:, None]
        emit(points[:, None] + off, torch.zeros((n, cfg.n_surface), device=dev, dtype=dt), SURFACE)
    if cfg.n_front > 0:
        lo, hi = cfg.front_range
        lam = uniform(cfg.n_front, lo, hi)
        emit(e + lam[..., None] * d[:, None], (1.0 - lam) * dist, FRONT)
    if cfg.n_behind > 0:
        lam = uniform(cfg.n_behind, 1.0 + cfg.behind_min, 1.0 + cfg.behind_max)
        emit(e + lam[..., None] * d[:, None], (1.0 - lam) * dist, BEHIND)
    return RaySamples(torch.cat(out_p), torch.cat(out_s), torch.cat(out_k), torch.cat(out_r))
