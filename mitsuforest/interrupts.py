"""Interrupts: Ctrl-C (SIGINT) and SIGTERM, which schedulers send, both stop a render cleanly.

Some moments must not be cut: a C extension's import (Mitsuba and Dr.Jit crash when an interrupt
lands half-way; trimesh's import swallows it, so it is imported where a mesh is read by
:func:`import_held`) and the final move of finished files into place. Those run inside
:func:`deferred_signals`, which notes a signal and acts on it when the block ends.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
from contextlib import contextmanager


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: clean up, then exit 143."""


class InterruptedAfterCommit(KeyboardInterrupt):
    """A signal that arrived while finished files were moved into place: they are all there."""

    def __init__(self, terminated: bool):
        super().__init__()
        self.terminated = terminated   # SIGTERM rather than SIGINT


class StoppedWithWorkKept(KeyboardInterrupt):
    """A signal that stopped a command whose finished work is kept (a dataset's finished plots):
    ``kept`` says what, in words."""

    def __init__(self, kept: str, terminated: bool):
        super().__init__(kept)
        self.kept, self.terminated = kept, terminated


def raise_terminated(signum, frame):
    """A SIGTERM handler."""
    raise Terminated()


def quiet_signals_until_exit() -> None:
    """Once a command has ended: a Ctrl-C or SIGTERM while the interpreter shuts down (joining threads,
    running exit handlers) ends the process at once with one line and the usual code (130, 143), not a
    traceback or a silent kill."""
    def leave(signum, frame):
        name = "stopped (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):   # a closed pipe or stream: nothing more to say there
                pass
        os.write(2, f"mitsuforest: {name} while exiting, after the command had ended\n".encode())
        os._exit(128 + signum)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, leave)


def in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def deferred_signals(ignore: bool = False):
    """Hold SIGINT and SIGTERM while a block runs, then act on them (raise :class:`KeyboardInterrupt`
    or :class:`Terminated`), or with ``ignore`` drop them (a block that cleans up after one).

    The signals are only noted during the block (Python runs handlers in the main thread, whichever
    thread the OS delivers them to); off the main thread the block runs as it is.
    """
    if not in_main_thread():
        yield
        return
    pending = []
    previous = {sig: signal.signal(sig, lambda signum, frame: pending.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        # Python runs a pending signal's handler right after any call: a handler put back may act at once
        # and raise, so each put is in a finally of the one before, SIGINT's (the noting one until then) last.
        try:
            signal.signal(signal.SIGTERM, previous[signal.SIGTERM])
        finally:
            signal.signal(signal.SIGINT, previous[signal.SIGINT])
    if pending and not ignore:
        raise Terminated() if signal.SIGTERM in pending else KeyboardInterrupt()


def dask_setup(worker) -> None:
    """Dask's preload hook (``preload=["mitsuforest.interrupts"]``): a worker process of the embedded
    LocalCluster ignores Ctrl-C, which the terminal sends to the whole process group, and leaves it to
    the client, which stops the workers and reports once (no worker tracebacks)."""
    if in_main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def held_while_loading(module: str):
    """:func:`deferred_signals` around a block that imports ``module``, unless it is loaded already (then
    the block is left as it is): Mitsuba's first ``set_variant`` of a variant, trimesh where a mesh is read."""
    if module in sys.modules:
        yield
        return
    with deferred_signals():
        yield


def import_held(name: str):
    """The module ``name``, imported with signals held when it is not loaded yet (:func:`held_while_loading`):
    for trimesh, whose import swallows an interrupt, imported only where a mesh is read."""
    with held_while_loading(name):
        return importlib.import_module(name)
