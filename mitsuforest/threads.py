"""Host threads for the numpy work on each batch of points: how many, and a batch cut into row ranges
that they handle side by side (the scan's point array, the writer's encoding and statistics); and
:class:`ReadAhead`, on which the device traces the scan's next batch while the host handles this one.

numpy's copies, casts and arithmetic and the kernel's file writes release the GIL, so threads handle
the parts of one batch in parallel. Each part lands at its own rows or file offset, so the bytes
written do not depend on the number of threads.
"""

from __future__ import annotations

import os
import queue
import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait

from .errors import UserError

THREADS_VARIABLE = "MITSUFOREST_WRITER_THREADS"
MIN_ROWS = 32768   # the smallest part worth a task of its own


def writer_threads() -> int:
    """The thread count for the points' host work: ``MITSUFOREST_WRITER_THREADS`` if set, else the
    cores this process may run on.

    :raises UserError: for a value that is not a whole number of at least 1.
    """
    text = os.environ.get(THREADS_VARIABLE, "").strip()
    if text:
        if not text.isdigit() or int(text) < 1:
            raise UserError(f"{THREADS_VARIABLE}: must be a whole number >= 1, got {text!r}")
        return int(text)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def row_ranges(count: int, parts: int, minimum: int = MIN_ROWS) -> list[tuple[int, int]]:
    """``count`` rows as at most ``parts`` contiguous ``(start, stop)`` ranges of about equal size,
    none below ``minimum`` rows unless there is only one."""
    parts = max(1, min(parts, count // max(minimum, 1)))
    edges = [count * k // parts for k in range(parts + 1)]
    return list(zip(edges[:-1], edges[1:]))


class Workers:
    """Runs tasks on ``threads`` threads, or at once in the calling thread when ``threads`` is 1."""

    def __init__(self, threads: int):
        self.threads = threads
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="mitsuforest-writer") if threads > 1 else None

    def submit(self, fn, *args) -> Future:
        if self._pool is not None:
            return self._pool.submit(fn, *args)
        done: Future = Future()
        try:
            done.set_result(fn(*args))
        except BaseException as e:  # noqa: BLE001 (raised by results(), as a pool's would be)
            done.set_exception(e)
        return done

    @staticmethod
    def results(futures: list[Future]) -> list:
        """The tasks' results in order, once all have finished (none is left writing); the first
        failed task's exception is raised."""
        wait(futures)
        return [f.result() for f in futures]

    @staticmethod
    def finish(futures: list[Future]) -> None:
        """Wait until the tasks have finished, whatever their outcome."""
        wait(futures)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)


_shared: Workers | None = None


def _forget_shared() -> None:
    global _shared
    _shared = None   # a forked child has none of its parent's threads: it makes its own


os.register_at_fork(after_in_child=_forget_shared)


def shared_workers() -> Workers:
    """A process-wide :class:`Workers` of :func:`writer_threads` threads, made on first use."""
    global _shared
    if _shared is None:
        _shared = Workers(writer_threads())
    return _shared


class ReadAhead:
    """The items of ``items`` in order, made up to ``depth`` ahead on a thread of their own: the device
    traces the scan's next batch while the caller makes the points of this one, labels and writes them
    (Dr.Jit waits for its kernels, and numpy works, without Python's lock). An exception raised making
    an item is raised again where that item would have come. :meth:`close`, or the end of a ``with``
    block, stops the thread once the item it is making is made."""

    _END = object()

    def __init__(self, items, depth: int = 1):
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._ended = False
        self._thread = threading.Thread(target=self._run, args=(iter(items),), name="mitsuforest-scan", daemon=True)
        self._thread.start()

    def _run(self, items) -> None:
        try:
            for item in items:
                if not self._put((item, None)):
                    return
        except BaseException as e:  # noqa: BLE001 (raised again in the caller's thread)
            self._put((self._END, e))
            return
        self._put((self._END, None))

    def _put(self, entry) -> bool:
        """Queue ``entry`` once there is room, unless stopped first (then False)."""
        while not self._stop.is_set():
            try:
                self._queue.put(entry, timeout=0.1)
                return True
            except queue.Full:
                pass
        return False

    def __iter__(self):
        return self

    def __next__(self):
        if self._ended:
            raise StopIteration
        item, error = self._queue.get()
        if item is self._END:
            self._ended = True
            self._thread.join()
            if error is not None:
                raise error
            raise StopIteration
        return item

    def close(self) -> None:
        self._stop.set()
        self._thread.join()

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
