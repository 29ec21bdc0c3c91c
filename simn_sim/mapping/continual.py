"""Replay of closed local frames for the decoder they share (continual learning across frames).

Local frames that share one decoder ``F_theta`` (``SlamConfig.share_decoder``) keep their own
neural points in their own anchor coordinates, so a sample of an earlier frame means nothing
in a later frame's coordinates: decoded with the later frame's neighbours it would carry a
wrong label. :class:`FrameReplay` therefore stores, for samples of each closed frame, the
decoder *inputs* gathered from that frame's neural points when it closed (interpolated
feature, colour, relative position, and the prior's weights / plane distances where the
decoder has them) with their SDF labels. A closed frame's features no longer change, so these
inputs are exact; later frames' training decodes them with the current decoder and adds their
BCE to the batch (:meth:`~simn_sim.mapping.mapper.ImplicitMap.train`).

The pool is bounded (``capacity`` samples) and split evenly over the closed frames: when a
frame joins, every earlier frame keeps a random subset of its share, so the first frame is
never crowded out by the later ones.
"""

from __future__ import annotations

import torch

__all__ = ["FrameReplay"]


class FrameReplay:
    """Frozen decoder inputs + SDF labels of samples of closed local frames (module docstring).

    Shared by reference between the maps that share a decoder; ``device``: where the tensors
    live.
    """

    def __init__(self, capacity: int, device: str | torch.device = "cpu") -> None:
        self.capacity = int(capacity)
        self.device = torch.device(device)
        self.entries: list[tuple[tuple[torch.Tensor, ...], torch.Tensor]] = []
        self._cat: tuple[tuple[torch.Tensor, ...], torch.Tensor] | None = None

    def __len__(self) -> int:
        return sum(int(s.shape[0]) for _, s in self.entries)

    @property
    def n_frames(self) -> int:
        """Closed frames represented in the pool."""
        return len(self.entries)

    def share(self, extra_frames: int = 1) -> int:
        """Samples each frame keeps once ``extra_frames`` more have joined."""
        return self.capacity // max(len(self.entries) + extra_frames, 1)

    def add_frame(
        self,
        inputs: tuple[torch.Tensor, ...],
        sdf: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> None:
        """Add one closed frame's samples (decoder inputs, each with leading dim N, and (N,)
        labels); every frame is then cut to an equal share (random subsets, ``generator``)."""
        n = int(sdf.shape[0])
        if n == 0 or self.capacity == 0:
            return
        if self.entries and len(inputs) != len(self.entries[0][0]):
            raise ValueError("FrameReplay: decoder inputs differ from the earlier frames'")
        q = self.share(1)
        if q == 0:
            return
        entries = [*self.entries, (tuple(t.detach() for t in inputs), sdf.detach())]
        out = []
        for inp, s in entries:
            if s.shape[0] > q:
                sel = torch.randperm(s.shape[0], generator=generator, device=self.device)[:q]
                inp, s = tuple(t[sel] for t in inp), s[sel]
            out.append((inp, s))
        self.entries = out
        self._cat = None

    def _concat(self) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        if self._cat is None:
            k = len(self.entries[0][0])
            self._cat = (
                tuple(torch.cat([e[0][i] for e in self.entries]) for i in range(k)),
                torch.cat([e[1] for e in self.entries]),
            )
        return self._cat

    def draw(
        self, n: int, generator: torch.Generator | None = None
    ) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        """``n`` samples drawn uniformly with replacement: (inputs, labels)."""
        return self.take(self.draw_ids(n, generator))

    def draw_ids(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """The indices :meth:`draw` takes (the same generator draws)."""
        return torch.randint(len(self), (n,), generator=generator, device=self.device)

    def take(self, ids: torch.Tensor) -> tuple[tuple[torch.Tensor, ...], torch.Tensor]:
        """The samples at ``ids`` (from :meth:`draw_ids`): (inputs, labels)."""
        inp, s = self._concat()
        return tuple(t[ids] for t in inp), s[ids]

    def nbytes(self) -> int:
        return int(sum(t.numel() * t.element_size() for inp, s in self.entries for t in (*inp, s)))

    def state_dict(self) -> dict:
        return {
            "capacity": self.capacity,
            "inputs": [list(inp) for inp, _ in self.entries],
            "sdf": [s for _, s in self.entries],
        }

    def load_state_dict(self, state: dict) -> None:
        self.capacity = int(state["capacity"])
        self.entries = [
            (tuple(t.to(self.device) for t in inp), s.to(self.device))
            for inp, s in zip(state["inputs"], state["sdf"], strict=True)
        ]
        self._cat = None
