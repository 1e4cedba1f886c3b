"""Errors a user can act on. The CLI prints them as one line and exits with code 2."""

from __future__ import annotations

from pathlib import Path


def display_path(path) -> Path:
    """A path as a user would write it: relative to the working folder when inside it."""
    path = Path(path)
    try:
        return path.resolve().relative_to(Path.cwd())
    except ValueError:
        return path


def amount(value: float, decimals: int = 0) -> str:
    """A measure for a message: with thousands separators, or in powers of ten when it is huge (300
    digits of a leg of 1e300 m say nothing more)."""
    return f"{value:,.{decimals}f}" if abs(value) < 1e15 else f"{value:.3g}"


class UserError(Exception):
    """A problem with the user's input or environment, reported without a traceback."""

    exit_code = 2


class ConfigError(UserError):
    """An invalid value in a configuration file, reported as ``FILE: key.path: reason``."""

    def __init__(self, file, key: str, reason: str):
        self.file = str(file)
        self.key = key
        self.reason = reason
        where = f"{self.file}: {key}: " if key else f"{self.file}: "
        super().__init__(where + reason)

    def __reduce__(self):   # pickled whole (Dask sends a worker's errors to the client)
        return type(self), (self.file, self.key, self.reason)
