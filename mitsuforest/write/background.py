"""A worker thread that consumes point batches, so writing one batch overlaps scanning the next."""

from __future__ import annotations

import queue
import threading


class Background:
    """Calls ``consume(batch)`` for each batch on one worker thread, in order.

    numpy and file writes release the GIL, so the writer runs while the scan's next batch is built
    and traced. An exception in ``consume`` is raised again by the next :meth:`__call__` or by
    :meth:`close`; later batches are then dropped.
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
        self._queue.put(batch)

    def close(self) -> None:
        """Wait until every batch is consumed; raise the worker's exception, if any."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        self._raise()

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error
