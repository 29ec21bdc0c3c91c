"""Local batch backends: in-process (``workers=0``) and a spawn process pool.

The pool uses the ``spawn`` start method (an EGL context must never be forked); at most
``workers`` episodes are in flight. A pool's processes are replaced after ``per_worker`` x
``workers`` episodes (the pool drains, closes, and a fresh one takes the rest): a worker's
resident memory grows with the episodes it has run (office_nav_v2, 320x240: 4.3-4.8 GB peak
after 9-10 episodes, 8-10 GB after about 20; docs/experiments.md), so a long run would
otherwise outgrow the machine. When a worker process dies (e.g. a segfault in a native
library) the episodes that were in flight run again one at a time in a fresh process, so that
the death is pinned on the right episode, which gets an error record after dying
:data:`~simn_sim.experiments.batch_worker.MAX_ATTEMPTS` times on its own.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import sys
from collections.abc import Callable, Sequence

from simn_sim.experiments.batch_worker import (
    MAX_ATTEMPTS,
    EpisodeResult,
    EpisodeTask,
    crash_result,
    limit_threads,
    run_task,
)

__all__ = ["ResultSink", "run_inprocess", "run_local"]

#: Called with each task and its result as soon as it is done (in the driver process).
ResultSink = Callable[[EpisodeTask, EpisodeResult], None]
TaskFn = Callable[[EpisodeTask], EpisodeResult]


def _worker_init(threads: int) -> None:
    """A pool process's initializer: :func:`limit_threads`, and on Linux the kernel ends the
    process when the batch process dies (``PR_SET_PDEATHSIG``): a batch killed outright would
    otherwise leave its workers running, each holding gigabytes."""
    limit_threads(threads)
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        pr_set_pdeathsig = 1
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(pr_set_pdeathsig, int(signal.SIGTERM), 0, 0, 0)
        parent = multiprocessing.parent_process()
        if parent is not None and os.getppid() != parent.pid:  # it died before the call
            os._exit(1)


def run_inprocess(tasks: Sequence[EpisodeTask], sink: ResultSink) -> None:
    """Run the tasks one after another in this process (debugging)."""
    for t in tasks:
        sink(t, run_task(t, limit=False))


def _pool_pass(
    queue: list[EpisodeTask],
    width: int,
    sink: ResultSink,
    fn: TaskFn,
    threads: int,
    budget: int = 0,
) -> list[EpisodeTask]:
    """Run tasks popped from ``queue`` in one spawn pool of ``width`` processes, at most
    ``width`` in flight and at most ``budget`` in all (0: no limit). Returns the tasks that
    were in flight when a worker process died (the pool is then unusable; the rest stay in
    ``queue``), or [] when ``queue`` ran empty or the budget was spent and all its tasks
    finished."""
    from concurrent.futures.process import BrokenProcessPool

    pool = cf.ProcessPoolExecutor(
        max_workers=width,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_worker_init,
        initargs=(threads,),
    )
    inflight: dict[cf.Future, EpisodeTask] = {}
    broken = False
    submitted = 0

    def more() -> bool:  # a task is waiting and the budget allows it
        return bool(queue) and (budget <= 0 or submitted < budget)

    try:
        while inflight or more():
            while len(inflight) < width and more():
                t = queue.pop()
                inflight[pool.submit(fn, t)] = t
                submitted += 1
            done, _ = cf.wait(inflight, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                try:
                    res = fut.result()
                except BrokenProcessPool:
                    broken = True
                    continue  # stays in flight: returned below
                except Exception as e:  # noqa: BLE001 - e.g. an unpicklable result
                    res = crash_result(inflight[fut], f"{type(e).__name__} in the worker: {e}")
                sink(inflight.pop(fut), res)
            if broken:
                return list(inflight.values())
        return []
    finally:
        pool.shutdown(wait=not broken, cancel_futures=True)


def run_local(
    tasks: Sequence[EpisodeTask],
    workers: int,
    sink: ResultSink,
    fn: TaskFn = run_task,
    per_worker: int = 0,
) -> None:
    """Process pool (spawn), at most ``workers`` episodes in flight; after ``per_worker`` x
    ``workers`` episodes (0: never) the pool drains and fresh processes run the rest.

    When a worker process dies, the episodes that were in flight are suspects: each runs again
    alone in a fresh one-process pool, so a death is pinned on the right episode; one whose
    process dies ``MAX_ATTEMPTS`` times on its own gets an error record, the others their
    normal record. ``fn``: the task function (module-level, so that a spawned worker can
    import it; tests swap it)."""
    queue = list(reversed(tasks))
    threads = tasks[0].threads if tasks else 1
    suspects: list[EpisodeTask] = []
    deaths: dict[int, int] = {}
    while queue or suspects:
        if suspects:
            t = suspects.pop()
            if _pool_pass([t], 1, sink, fn, threads):
                deaths[id(t)] = deaths.get(id(t), 0) + 1
                if deaths[id(t)] >= MAX_ATTEMPTS:
                    why = f"worker process died running this episode alone {deaths[id(t)]} times"
                    sink(t, crash_result(t, why))
                else:
                    suspects.append(t)
        else:
            budget = per_worker * workers if per_worker > 0 else 0
            suspects.extend(_pool_pass(queue, workers, sink, fn, threads, budget))
