"""Host threads for the numpy work on each batch of points: how many, and a batch cut into row ranges
that they handle side by side (the scan's point array, the writer's encoding and statistics); and
:class:`ReadAhead`, on which the device traces the scan's next batch while the host handles this one.

numpy's copies, casts and arithmetic and the kernel's file writes release the GIL, so threads handle
the parts of one batch in parallel. Each part lands at its own rows or file offset, so the bytes
written do not depend on the number of threads.
"""

from __future__ import annotations

import functools
import os
import queue
import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait

from .errors import UserError
from .interrupts import deferred_signals

THREADS_VARIABLE = "MITSUFOREST_WRITER_THREADS"
MIN_ROWS = 32768   # the smallest part worth a task of its own


def whole_number_variable(name: str, least: int) -> int | None:
    """The environment variable ``name`` as a whole number, None when it is not set (or blank).

    :raises UserError: for a value that is not a whole number of at least ``least``.
    """
    text = os.environ.get(name, "").strip()
    if not text:
        return None
    if not (text.isascii() and text.isdigit()) or int(text) < least:      # '²' is a digit to str.isdigit
        raise UserError(f"{name}: must be a whole number >= {least}, got {text!r}")
    return int(text)


def writer_threads() -> int:
    """The thread count for the points' host work: ``MITSUFOREST_WRITER_THREADS`` if set, else the
    cores this process may run on.

    :raises UserError: for a value that is not a whole number of at least 1.
    """
    threads = whole_number_variable(THREADS_VARIABLE, 1)
    if threads is not None:
        return threads
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


def on_row_ranges(count: int, task, *args) -> None:
    """``task(*args, start, stop)`` for ``count`` rows cut into :func:`row_ranges`, one range a thread of
    :func:`shared_workers`; returns once all have finished (the first failure raised)."""
    workers = shared_workers()
    workers.results([workers.submit(task, *args, start, stop) for start, stop in row_ranges(count, workers.threads)])


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
    global _shared, _readers
    _shared = _readers = None   # a forked child has none of its parent's threads: it makes its own


os.register_at_fork(after_in_child=_forget_shared)


_rendering_process: int | None = None      # the process that loaded a scene into Mitsuba, once one has


def note_native_threads() -> None:
    """Note that this process now runs the native thread pools a render starts (Mitsuba's and Embree's as
    a scene loads, Dr.Jit's as it scans, lazrs's as it compresses): a process forked from it has none of
    them, and :func:`refuse_forked_render` refuses to render there."""
    global _rendering_process
    _rendering_process = os.getpid()


def refuse_forked_render() -> None:
    """Refuse to render in a process forked from one that had rendered: its render would wait for ever on
    threads that did not come with the fork (the demo scene did, in Dr.Jit's and lazrs's waits).

    :raises UserError: in such a process.
    """
    if _rendering_process is not None and _rendering_process != os.getpid():
        raise UserError("this process was forked from one that had rendered (multiprocessing's 'fork', the default "
                        "on Linux before Python 3.14), and a render here would wait for ever on its parent's "
                        "Dr.Jit and LAZ threads, which a fork does not copy: start the rendering processes with "
                        "'spawn' (multiprocessing.get_context('spawn'); ProcessPoolExecutor(mp_context=...))")


def shared_workers() -> Workers:
    """A process-wide :class:`Workers` of :func:`writer_threads` threads, made on first use."""
    global _shared
    if _shared is None:
        _shared = Workers(writer_threads())
    return _shared


class ReadAhead:
    """The items of ``items`` in order, made ``depth`` ahead on a thread of their own: the device traces
    the scan's next batch while the caller makes the points of this one, labels and writes them (Dr.Jit
    waits for its kernels, and numpy works, without Python's lock). The thread makes an item only while
    fewer than ``depth`` made items wait to be taken. An exception raised making an item is raised again
    where that item would have come. :meth:`close`, or the end of a ``with`` block, stops the making once
    the item being made is made. The caller's release of a place holds Ctrl-C and SIGTERM until it is done
    (:func:`~mitsuforest.interrupts.deferred_signals`): an interrupt just after ``Semaphore.release`` took its
    lock left the lock taken, the making thread then waited on it for ever, and :meth:`close` on that
    thread."""

    _END = object()

    def __init__(self, items, depth: int = 1):
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._room = threading.Semaphore(depth)
        self._stop, self._done = threading.Event(), threading.Event()
        self._maker: int | None = None        # the making thread's ident
        self._ended = False
        _reader_threads().run(functools.partial(self._make, iter(items)))

    def _make(self, items) -> None:
        self._maker = threading.get_ident()
        try:
            while self._wait_for_room():
                try:
                    item = next(items)
                except StopIteration:
                    self._queue.put((self._END, None))
                    return
                self._queue.put((item, None))
        except BaseException as e:  # noqa: BLE001 (raised again in the caller's thread)
            self._queue.put((self._END, e))
        finally:
            self._done.set()

    def _wait_for_room(self) -> bool:
        """Take a place for the next item; False once stopped."""
        while not self._stop.is_set():
            if self._room.acquire(timeout=0.1):
                return not self._stop.is_set()
        return False

    def __iter__(self):
        return self

    def __next__(self):
        if self._ended:
            raise StopIteration
        item, error = self._queue.get()
        if item is self._END:
            self._ended = True
            self._done.wait()
            if error is not None:
                raise error
            raise StopIteration
        with deferred_signals():
            self._room.release()
        return item

    def close(self) -> None:
        """Stop making items and wait for the one being made (not when the making thread itself closes
        it, as a garbage collection there may)."""
        self._stop.set()
        self._ended = True
        if threading.get_ident() != self._maker:
            self._done.wait()

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _ReaderThreads:
    """Daemon threads that make read-aheads' items, kept for the process: Dr.Jit keeps a thread's state
    (on a GPU its CUDA stream) until the process ends, so a scan after another takes the idle thread of
    the last, and only scans that run at once have threads of their own."""

    def __init__(self):
        self._idle: queue.SimpleQueue = queue.SimpleQueue()     # the idle threads' inboxes

    def run(self, task) -> None:
        """Run ``task()`` (which raises nothing) on an idle thread, or a new one."""
        try:
            inbox = self._idle.get_nowait()
        except queue.Empty:
            inbox = queue.SimpleQueue()
            threading.Thread(target=self._serve, args=(inbox,), name="mitsuforest-scan", daemon=True).start()
        inbox.put(task)

    def _serve(self, inbox: queue.SimpleQueue) -> None:
        while True:
            task = inbox.get()
            task()
            task = None          # the task's items let go before the thread waits for the next
            self._idle.put(inbox)


_readers: _ReaderThreads | None = None


def _reader_threads() -> _ReaderThreads:
    global _readers
    if _readers is None:
        _readers = _ReaderThreads()
    return _readers
