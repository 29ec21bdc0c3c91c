"""Training of the learned local-frame maps on a worker thread (``SlamConfig.train_async``).

:meth:`SimnSlam.process` queues the frame's training chunk (``ImplicitMap.train``) when it
integrates the frame, starts it here as its last step (after the revisit check, which reads the
map) and returns; the chunk runs while the caller plans, steps the env and perceives the next
frame (torch releases the GIL), and the next :meth:`~SimnSlam.process` joins it before it
tracks. Nothing reads or writes the map in between (perception does not touch it), so the map
that frame t+1 is tracked against is the one the synchronous path would have: the estimated
poses are bit-identical. Only the bookkeeping that follows a training (the frame's trained
count and its topological node's descriptor and region) happens at the join, one step later.

The worker thread sets its own torch intra-op threads (OpenMP's setting is per thread) and
denormal flushing is per thread too, so neither leaks into the caller.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import torch

__all__ = ["TrainWorker"]


class TrainWorker:
    """One training job at a time on one worker thread; :meth:`join` waits for it and runs its
    completion callback on the caller's thread. Totals over the jobs run on the thread:
    ``wait_ms``, the time joins waited; ``run_ms``, the jobs' wall time on the worker;
    ``beside_ms``, the caller's time from :meth:`start` to the join (its work beside the job);
    ``between_ms``, the caller's time from a join to the next start (the worker idles). A job
    is hidden while ``run_ms <= beside_ms``; the wait is the difference. Per job the caller's
    cycle is ``beside_ms + wait_ms + between_ms``."""

    def __init__(self, threads: int = 1, inline: bool = False) -> None:
        self.threads = int(threads)
        self.inline = bool(inline)  # no thread: a job runs at join, on the caller's thread
        self._ex: ThreadPoolExecutor | None = None
        self._job: tuple[Future, Callable[[Any], None]] | None = None
        self._queued: tuple[Callable[[], Any], Callable[[Any], None]] | None = None
        self.jobs = 0
        self.wait_ms = 0.0
        self.last_wait_ms = 0.0
        self.run_ms = 0.0
        self.beside_ms = 0.0
        self.between_ms = 0.0
        self._t_start = 0.0
        self._t_joined: float | None = None
        self._last_run_ms = 0.0

    def _init_thread(self) -> None:
        if self.threads > 0:
            torch.set_num_threads(self.threads)

    @property
    def busy(self) -> bool:
        return self._job is not None or self._queued is not None

    def submit(self, fn: Callable[[], Any], done: Callable[[Any], None]) -> None:
        """Queue ``fn()`` for the worker; it starts at :meth:`start` (the caller's last use of
        the map in its step) and ``done(result)`` runs at the next :meth:`join`."""
        self.join()
        self._queued = (fn, done)

    def start(self) -> None:
        """Start the queued job on the worker thread (no-op without one, or ``inline``)."""
        if self._queued is None or self.inline:
            return
        fn, done = self._queued
        self._queued = None
        if self._ex is None:
            self._ex = ThreadPoolExecutor(
                1, thread_name_prefix="simn-train", initializer=self._init_thread
            )
        self._t_start = time.perf_counter()
        if self._t_joined is not None:
            self.between_ms += (self._t_start - self._t_joined) * 1e3
        self._job = (self._ex.submit(self._timed, fn), done)
        self.jobs += 1

    def _timed(self, fn: Callable[[], Any]) -> Any:
        t = time.perf_counter()
        try:
            return fn()
        finally:  # read by the caller after the future's result (which orders the two)
            self._last_run_ms = (time.perf_counter() - t) * 1e3

    def join(self) -> None:
        """Wait for the running job (re-raising its exception) and run its callback; a job
        queued but not started runs here, on the caller's thread."""
        if self._queued is not None:
            fn, done = self._queued
            self._queued = None
            done(fn())
        if self._job is None:
            return
        fut, done = self._job
        self._job = None
        t = time.perf_counter()
        self.beside_ms += (t - self._t_start) * 1e3
        res = fut.result()
        self.last_wait_ms = (time.perf_counter() - t) * 1e3
        self.wait_ms += self.last_wait_ms
        self.run_ms += self._last_run_ms
        self._t_joined = time.perf_counter()
        done(res)

    def close(self) -> None:
        """Join and stop the thread."""
        try:
            self.join()
        finally:
            if self._ex is not None:
                self._ex.shutdown(wait=True)
                self._ex = None
