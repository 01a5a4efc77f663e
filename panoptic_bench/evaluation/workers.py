"""How an evaluation runs its items: how many worker processes, the pool, the progress bar.

This module is the one place of the policy. ``--workers N`` is an upper bound: a process pool
costs tens of milliseconds (fork, queues, shutdown) while a scan scores in a few, and a second
process only helps when a second CPU is free. :func:`pool_size` therefore starts

- at most one worker per :data:`MIN_ITEMS_PER_WORKER` scans / sweeps,
- at most one worker per independent job (e.g. a scene),
- at most one worker per free CPU (:func:`free_cpus`: the CPUs this process may use, minus the
  other processes running now),

and prints one line on stderr when it starts fewer than asked. Results never depend on it (the
accumulators add up exactly, in input order). :func:`retain_freed_memory` keeps the C allocator
from handing each scan's temporary arrays back to the system. Heavy imports (``concurrent.futures``, ``tqdm``)
happen only when a pool or a visible progress bar is actually used.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

__all__ = [
    "MIN_ITEMS_PER_WORKER",
    "free_cpus",
    "pool_map",
    "pool_size",
    "progress_bar",
    "retain_freed_memory",
]

#: scans / sweeps a worker must get for a pool to pay off (tests lower it to exercise pools)
MIN_ITEMS_PER_WORKER = 64


def free_cpus() -> tuple[int, str]:
    """CPUs free for this process now, and a few words saying why.

    The CPUs of ``os.sched_getaffinity(0)`` minus the busy ones: the processes running now
    other than this one (``/proc/loadavg``), or the 1-minute load average where that is
    unavailable, whichever is smaller (a finished run still weighs on the load average).

    Returns
    -------
    (int, str)
        At least 1, and e.g. ``"2 CPUs, 2.0 busy"``.
    """
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    busy = 0.0
    try:
        busy = os.getloadavg()[0]
    except (AttributeError, OSError):
        pass
    try:
        with open("/proc/loadavg", encoding="ascii") as fh:
            running = int(fh.read().split()[3].split("/")[0])
        busy = min(busy, max(running - 1, 0))
    except (OSError, ValueError, IndexError):
        pass
    return max(1, cpus - int(busy + 0.5)), f"{cpus} CPUs, {busy:.1f} busy"


def pool_size(workers: int, n_items: int, n_jobs: int | None = None, *, quiet: bool = False) -> int:
    """Worker processes to start: 1 means score in this process.

    Parameters
    ----------
    workers : int
        The ``--workers`` option (>= 1).
    n_items : int
        Scans or sweeps to score.
    n_jobs : int, optional
        Independent jobs the items are grouped in (e.g. scenes); at most one worker per job.
    quiet : bool
        Do not print the line saying why fewer workers start than asked.

    Returns
    -------
    int
        In ``[1, workers]``.
    """
    if workers <= 1:
        return 1
    n, why = workers, ""
    by_items = n_items // MIN_ITEMS_PER_WORKER
    if by_items < n:
        n, why = by_items, f"{n_items} items, {MIN_ITEMS_PER_WORKER} needed per worker"
    if n_jobs is not None and n_jobs < n:
        n, why = n_jobs, f"{n_jobs} independent jobs"
    if n > 1:
        free, load = free_cpus()
        if free < n:
            n, why = free, f"{free} free CPU(s): {load}"
    n = max(1, n)
    if n < workers and not quiet:
        print(
            f"panoptic-bench: --workers {workers}: using {n} process{'es' if n > 1 else ''} "
            f"({why})",
            file=sys.stderr,
        )
    return n


@contextmanager
def pool_map(
    func: Callable[[Any], Any], items: Sequence[Any], n_workers: int, chunksize: int = 1
) -> Iterator[Iterable[Any]]:
    """``map(func, items)`` in this process (``n_workers == 1``) or in a forked pool.

    Results come in input order; the pool is shut down (pending items cancelled) on exit.
    """
    if n_workers <= 1 or len(items) <= 1:
        yield map(func, items)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    methods = mp.get_all_start_methods()
    ctx = mp.get_context("fork" if "fork" in methods else "spawn")
    pool = ProcessPoolExecutor(min(n_workers, len(items)), mp_context=ctx)
    try:
        yield pool.map(func, items, chunksize=chunksize)
    finally:
        pool.shutdown(cancel_futures=True)


class _NoBar:
    """Stands in for a disabled ``tqdm`` bar (``update`` / ``close`` do nothing)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress_bar(total: int, desc: str, unit: str, progress: bool | None = None) -> Any:
    """A ``tqdm`` progress bar, imported only when it will show.

    Parameters
    ----------
    total : int
    desc, unit : str
    progress : bool or None
        True: always; False: never; None: only when stderr is a terminal (as ``tqdm``'s
        ``disable=None``).

    Returns
    -------
    object with ``update(n)`` and ``close()``
    """
    if progress is False:
        return _NoBar()
    if progress is None:
        try:
            if sys.stderr is None or not sys.stderr.isatty():
                return _NoBar()
        except (AttributeError, ValueError):
            return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=False)


#: glibc ``mallopt`` parameters
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def retain_freed_memory(limit: int = 1 << 25) -> bool:
    """Let this process reuse freed memory instead of returning it to the system (glibc).

    By default glibc unmaps a freed block above 128 KiB-32 MiB and trims the heap top above
    twice that, so every scan's temporary arrays (a few MB) are mapped and page-faulted again:
    about 2.5 ms of system time per SemanticKITTI scan, as much as scoring it. Raising both
    thresholds to ``limit`` keeps up to that much freed memory for reuse. Elsewhere (no glibc)
    nothing changes.

    Parameters
    ----------
    limit : int
        Bytes (at most 32 MiB, glibc's ceiling for the mmap threshold).

    Returns
    -------
    bool
        True if the allocator accepted both settings.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_TRIM_THRESHOLD, 2 * limit) and mallopt(_M_MMAP_THRESHOLD, limit))
