"""Process-wide pools of worker processes, shared by the stages that spread their work over the cores: the
trees stage builds models in them (:func:`mitsuforest.trees.build_models`), the writer writes parts of its
batches (:mod:`mitsuforest.write.processes`). A pool of a given size is started once a process and kept for
later plots; a broken one (a worker killed) is replaced.

The workers are fresh interpreters (``spawn``: no copy of this process's threads, Dr.Jit's and CUDA's among
them) that ignore Ctrl-C: it reaches the whole process group, and the parent, not each worker, answers it.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import types
from concurrent.futures import ProcessPoolExecutor

_POOLS: dict[int, ProcessPoolExecutor] = {}
MANY_CORES = 8    # from this many cores on, a pool leaves one to the process that uses it


def usable_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:      # not Linux
        return os.cpu_count() or 1


def worker_count(cores: int | None = None) -> int:
    """The workers a pool has by default on ``cores`` (this process's by default): one less than the cores
    from :data:`MANY_CORES` on, all of them below; so the stages that ask for the default share one pool."""
    cores = usable_cores() if cores is None else cores
    return cores - 1 if cores >= MANY_CORES else cores


def may_start_processes() -> bool:
    """Whether this process may have worker processes: not a daemonic one (multiprocessing refuses them
    children), as a process pool's own workers are."""
    return not multiprocessing.current_process().daemon


def process_pool(processes: int) -> ProcessPoolExecutor:
    """The process-wide pool of ``processes`` workers, started (not waited for) on first use."""
    pool = _POOLS.get(processes)
    if pool is None or getattr(pool, "_broken", False):
        pool = _POOLS[processes] = _started_pool(processes)
    return pool


def _started_pool(processes: int) -> ProcessPoolExecutor:
    # A spawned worker runs the parent's main module first (multiprocessing's rule), which for a script
    # that renders at its top level, with no ``if __name__ == "__main__"``, would render again in every
    # worker: all of them start now, while the main module is an empty one.
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        pool = ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_ignore_interrupts)
        for _ in range(processes):        # each submit starts one more worker while none is idle
            pool.submit(_ready)
    finally:
        sys.modules["__main__"] = main
    return pool


def _ignore_interrupts() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _ready() -> None:
    """A task that makes the pool start a worker."""
