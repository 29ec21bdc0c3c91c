"""A bounded pool of old training samples (reservoir sampling), mixed into new batches."""

from __future__ import annotations

import torch


class ReplayPool:
    """Keeps at most ``capacity`` samples (position (3,), label, kind), each sample seen so
    far being kept with equal probability (reservoir sampling, vectorised)."""

    def __init__(self, capacity: int, device: str | torch.device = "cpu") -> None:
        self.capacity = int(capacity)
        self.device = torch.device(device)
        self.points = torch.empty((0, 3), device=self.device)
        self.sdf = torch.empty((0,), device=self.device)
        self.kind = torch.empty((0,), dtype=torch.int8, device=self.device)
        self.seen = 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def add(
        self,
        points: torch.Tensor,
        sdf: torch.Tensor,
        kind: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> None:
        n = points.shape[0]
        if n == 0 or self.capacity == 0:
            self.seen += n
            return
        room = max(self.capacity - len(self), 0)
        take = min(room, n)
        if take:
            self.points = torch.cat([self.points, points[:take]])
            self.sdf = torch.cat([self.sdf, sdf[:take]])
            self.kind = torch.cat([self.kind, kind[:take]])
        rest = n - take
        if rest:
            # sample i (0-based over all seen) replaces slot j ~ U{0..i} when j < capacity
            i = torch.arange(
                self.seen + take, self.seen + n, device=self.device, dtype=torch.float64
            )
            u = torch.rand(rest, generator=generator, device=self.device, dtype=torch.float64)
            j = torch.floor(u * (i + 1)).long()
            keep = j < self.capacity
            src = torch.arange(take, n, device=self.device)[keep]
            j = j[keep]
            if j.numel():
                # a slot hit twice keeps the later sample, as sequential reservoir sampling would
                rev_j = torch.flip(j, [0])
                uniq, inv = torch.unique(rev_j, return_inverse=True)
                first_rev = torch.full(
                    (uniq.numel(),), rev_j.numel(), dtype=torch.long, device=self.device
                )
                first_rev.scatter_reduce_(
                    0, inv, torch.arange(rev_j.numel(), device=self.device), "amin"
                )
                last = j.numel() - 1 - first_rev
                self.points[j[last]] = points[src[last]]
                self.sdf[j[last]] = sdf[src[last]]
                self.kind[j[last]] = kind[src[last]]
        self.seen += n

    def sample(self, n: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, ...]:
        """``n`` samples drawn without replacement (all if the pool is smaller)."""
        m = len(self)
        if n >= m:
            return self.points, self.sdf, self.kind
        sel = torch.randperm(m, generator=generator, device=self.device)[:n]
        return self.points[sel], self.sdf[sel], self.kind[sel]

    def state_dict(self) -> dict:
        return {"points": self.points, "sdf": self.sdf, "kind": self.kind, "seen": self.seen}

    def load_state_dict(self, state: dict) -> None:
        self.points = state["points"].to(self.device)
        self.sdf = state["sdf"].to(self.device)
        self.kind = state["kind"].to(self.device)
        self.seen = int(state["seen"])
