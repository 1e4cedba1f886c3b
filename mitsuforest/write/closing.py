"""The manners of laspy's writer, shared by every stream that writes a file batch by batch."""

from __future__ import annotations


class Closing:
    """A file written batch by batch that, as a context manager, is closed at the end of its block or,
    after an error, aborted; once closed either way it refuses writes, and closing it again does nothing.

    A subclass finishes its file in :meth:`_finish`, discards what it holds in :meth:`_discard` (which
    runs after a :meth:`_finish` that failed, and may run after one that succeeded) and calls
    :meth:`_refuse_if_closed` before each write.
    """

    closed = False

    def __enter__(self):
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    def close(self) -> None:
        """Finish the file (a second call does nothing); if that fails, discard it and raise."""
        if self.closed:
            return
        self.closed = True
        try:
            self._finish()
        except BaseException:
            self._discard()
            raise

    def abort(self) -> None:
        """Give up the file after a failure, possibly one inside :meth:`close`; raises nothing of its own."""
        self.closed = True
        self._discard()

    def _refuse_if_closed(self) -> None:
        if self.closed:
            raise ValueError(f"{getattr(self, 'path', '')}: write to a closed {type(self).__name__}".lstrip(": "))

    def _finish(self) -> None:
        raise NotImplementedError

    def _discard(self) -> None:
        raise NotImplementedError
