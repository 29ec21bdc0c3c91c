"""The training worker's bookkeeping (``TrainWorker``): a job runs inside the interval from its
start to the end of its join, so its wall time is at most the caller's time beside it plus
the join's wait; errors of a job reach the caller at the join."""

import threading
import time

import pytest

from simn_sim.slam.trainer import TrainWorker


def test_job_time_is_covered_by_the_work_beside_it_and_the_wait():
    w = TrainWorker(threads=1)
    go = threading.Event()
    done = []

    def job():
        go.wait()
        time.sleep(0.03)
        return 7

    try:
        for _ in range(2):
            w.submit(job, done.append)
            w.start()
            time.sleep(0.02)  # the caller's work beside the job; the job cannot finish first
            go.set()
            w.join()
            go.clear()
            time.sleep(0.01)  # the caller's work between a join and the next start
    finally:
        w.close()
    assert done == [7, 7] and w.jobs == 2
    assert w.run_ms >= 2 * 30 and w.beside_ms >= 2 * 20
    assert w.run_ms <= w.beside_ms + w.wait_ms + 1e-6
    assert w.between_ms >= 10  # one gap: from the first join to the second start


def test_a_failing_job_raises_at_the_join():
    w = TrainWorker(threads=1)

    def job():
        raise ValueError("chunk failed")

    try:
        w.submit(job, lambda _res: None)
        w.start()
        with pytest.raises(ValueError, match="chunk failed"):
            w.join()
    finally:
        w.close()
