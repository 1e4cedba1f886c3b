"""Models and crowns built in worker processes (:mod:`mitsuforest.pools`) when a plan needs many that no
cache holds: a tree list's or a plot's unique trees, or the trees of a twin's calibration, each grown
anew (a tree model took 0.3-0.8 CPU s on a 2-core EPYC, growing its crown 0.1 s). Each is built whole in
one worker, so it is the bytes the plan's own process would make; a worker's failure leaves that one to
the plan's process, which builds it (and raises its error) as without workers.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence

from ..pools import may_start_processes, process_pool, worker_count
from ..threads import whole_number_variable

PROCESSES_VARIABLE = "MITSUFOREST_BUILD_PROCESSES"
MIN_JOBS = 8      # builds worth the workers' start (about a CPU second each, importing the trees stage)
VARIABLES = "MITSUFOREST_"   # the settings a job runs under: the caller's now, not those a kept worker started with


def build_processes(cores: int | None = None) -> int:
    """Worker processes that build models and crowns: ``MITSUFOREST_BUILD_PROCESSES`` if set (0 or 1:
    none), else :func:`~mitsuforest.pools.worker_count` of ``cores`` (this process's: the pool the writer
    uses on many cores) from 2 on; none in a daemonic process.

    :raises UserError: for a value that is not a whole number of at least 0.
    """
    processes = whole_number_variable(PROCESSES_VARIABLE, 0)
    if processes is None:
        processes = worker_count(cores)
    return processes if processes >= 2 and may_start_processes() else 0


def in_workers(function: Callable, jobs: Sequence[tuple], processes: int | None = None) -> Iterator[tuple[bool, object]]:
    """``(True, function(*job))`` for each of ``jobs`` in order, each computed in a worker process, or
    ``(False, None)`` for the caller to compute: a job whose worker failed, and every job where there are
    fewer than :data:`MIN_JOBS` or :func:`build_processes` gives none. The jobs not yet started are
    cancelled when the caller stops early (an interrupt, an error)."""
    processes = build_processes() if processes is None else processes
    if processes < 2 or len(jobs) < MIN_JOBS:
        yield from ((False, None) for _ in jobs)
        return
    pool = process_pool(processes)
    variables = {k: v for k, v in os.environ.items() if k.startswith(VARIABLES)}
    futures = [pool.submit(_with_variables, variables, function, *job) for job in jobs]
    try:
        for future in futures:
            try:
                yield True, future.result()
            except Exception:   # noqa: BLE001  (the caller builds it itself, and raises its error there)
                yield False, None
    finally:
        for future in futures:
            future.cancel()


def _with_variables(variables: dict[str, str], function: Callable, *job):
    """A worker's job: ``function(*job)`` under the caller's ``MITSUFOREST_*`` variables (the model cache's
    folder and size among them), which may have changed since the pool started."""
    for name in [k for k in os.environ if k.startswith(VARIABLES) and k not in variables]:
        del os.environ[name]
    os.environ.update(variables)
    return function(*job)
