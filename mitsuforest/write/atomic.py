"""Atomic file writes: content goes to a temporary name in the same folder and is renamed when complete.

Temporary names carry their writer's :func:`owner_tag` (host and process id), so that a process
cleaning up removes only what it wrote itself or what a process that has died on this host left:
another render writing into the same folder, on this host or another sharing the file system, is
never disturbed.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import socket
from pathlib import Path

TMP_MARK = ".tmp-"


def owner_tag() -> str:
    """``HOST-PID`` of this process, for the names of its temporary files and folders."""
    return f"{socket.gethostname()}-{os.getpid()}"


def owner_is_gone(tag: str) -> bool:
    """Whether the process named by an :func:`owner_tag` has ended: only answerable on its own host
    (anything else, including a tag that cannot be parsed, counts as alive)."""
    host, _, pid = tag.rpartition("-")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    return not pid_alive(int(pid))


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host (a zombie counts as alive)."""
    if pid <= 0 or os.name == "nt":  # kill(0, ...) means the process group; on Windows kill terminates
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; rename it to ``path`` only if the block succeeds."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}{TMP_MARK}{owner_tag()}")
    try:
        yield tmp
        durable_replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def durable_replace(source, target) -> None:
    """Rename ``source`` to ``target`` so that a crash of the machine leaves the old file or the whole new
    one: ``source``'s content is flushed to disk before the rename, and the folder's entry after it."""
    fsync_file(source)
    os.replace(source, target)
    fsync_folder(Path(target).parent)


def fsync_file(path) -> None:
    """Flush a file's content to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_folder(path) -> None:
    """Flush a folder's entries (names renamed into it) to disk, where the system can: Windows opens no
    folder, and some file systems cannot sync one (EINVAL)."""
    if os.name == "nt":
        return
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as e:
        if e.errno != errno.EINVAL:
            raise
    finally:
        os.close(fd)


def write_text(path, text: str) -> None:
    with atomic_path(path) as tmp, naming_errors(path):
        tmp.write_text(text)


@contextlib.contextmanager
def naming_errors(path):
    """Give an OSError raised inside the block that names no file (a failing ``write`` does not) the
    name of ``path``, the file being written."""
    try:
        yield
    except OSError as e:
        if e.filename is None:
            raise OSError(e.errno, e.strerror or str(e), str(path)) from e
        raise


def write_json(path, data, indent: int = 1, **options) -> None:
    """``data`` as strict JSON: a nan or infinite float is written as ``null`` (``NaN`` is no JSON)."""
    write_text(path, json.dumps(finite_or_null(data), allow_nan=False, default=str, indent=indent, **options)
               + "\n")


def finite_or_null(value):
    """``value`` (nested dicts, lists, tuples, numbers) with every nan or infinite float as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    if hasattr(value, "dtype") and getattr(value, "shape", None) == ():   # a numpy scalar
        return finite_or_null(value.item())
    return value
