"""How many worker processes an evaluation starts.

A process pool costs tens of milliseconds (fork, queues, shutdown) while a scan scores in a few:
below :data:`MIN_ITEMS_PER_WORKER` items per worker one process is faster, so ``--workers N``
starts at most one worker per that many scans / sweeps. Results never depend on it (the
accumulators add up exactly, in input order).
"""

from __future__ import annotations

__all__ = ["MIN_ITEMS_PER_WORKER", "pool_size"]

#: scans / sweeps a worker must get for a pool to pay off (tests lower it to exercise pools)
MIN_ITEMS_PER_WORKER = 32


def pool_size(workers: int, n_items: int, n_jobs: int | None = None) -> int:
    """Worker processes to start: 1 means score in this process.

    Parameters
    ----------
    workers : int
        The ``--workers`` option (>= 1).
    n_items : int
        Scans or sweeps to score.
    n_jobs : int, optional
        Independent jobs the items are grouped in (e.g. scenes); at most one worker per job.
    """
    n = min(workers, n_items // MIN_ITEMS_PER_WORKER)
    if n_jobs is not None:
        n = min(n, n_jobs)
    return max(1, n)
