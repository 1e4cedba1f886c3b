"""A worker thread that consumes point batches, so writing one batch overlaps scanning the next."""

from __future__ import annotations

import queue
import threading

from ..interrupts import deferred_signals


class Background:
    """Calls ``consume(batch)`` for each batch on one worker thread, in order.

    numpy and file writes release the GIL, so the writer runs while the scan's next batch is built
    and traced. An exception in ``consume`` is raised again by the next :meth:`__call__` or by
    :meth:`close`; later batches are then dropped.

    The caller's puts hold Ctrl-C and SIGTERM (:func:`~mitsuforest.interrupts.deferred_signals`) and act
    on them once the batch is queued: an interrupt landing just after a put had taken the queue's lock
    left it taken (``with`` in Python's ``Condition.__enter__`` is cut there), and :meth:`close`, putting
    the end, then waited on that lock for ever. A put waits at most for the worker to take a batch.
    """

    def __init__(self, consume, depth: int = 4):
        self._consume = consume
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mitsuforest-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (batch := self._queue.get()) is not None:
            if self._error is None:
                try:
                    self._consume(batch)
                except BaseException as e:  # noqa: BLE001 (re-raised in the scanning thread)
                    self._error = e

    def __call__(self, batch) -> None:
        self._raise()
        with deferred_signals():
            self._queue.put(batch)

    def close(self) -> None:
        """Wait until every batch is consumed; raise the worker's exception, if any."""
        if self._thread.is_alive():
            with deferred_signals():
                self._queue.put(None)
            self._thread.join()
        self._raise()

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error
