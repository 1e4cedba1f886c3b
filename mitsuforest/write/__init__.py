"""Stage 6: every file a render writes (see README, "Outputs").

Points stream batch by batch into the point files (:class:`~.stream.PointWriter`). All files are
first written into a hidden staging folder inside ``output.dir`` and moved into place only
when all of them are complete, the manifest last: a render is finished exactly when
``<name>_manifest.json`` exists, and an interrupted one leaves nothing that looks finished.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
from concurrent.futures import wait
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fields import POINT_FORMATS
from ..interrupts import InterruptedAfterCommit, Terminated, deferred_signals

from .atomic import TMP_MARK, fsync_file, fsync_folder, owner_is_gone, owner_tag, write_json, write_text
from .las import write_las
from .pcd import read_pcd
from .output_profiles import PROFILE_SUFFIXES
from .figures import write_profile_figure, write_returns_figure, write_tile_figure, write_top_figure
from .parts import georeference
from .processes import draw_picture, shared_folder
from .stream import PointWriter
from .tables import write_ids, write_trajectory, write_volumes

__all__ = ["Staging", "check_output_folder", "output_lock", "PointWriter", "georeference", "output_files", "existing_outputs",
           "earlier_results", "refuse_finished_render", "write_plan", "read_pcd", "write_las", "write_render_outputs",
           "write_tables", "TABLES", "write_manifest"]

PLAN, MANIFEST = "_plan.json", "_manifest.json"
SUFFIXES = (*POINT_FORMATS.values(), "_volumes.csv", "_ids.csv", PLAN, "_trajectory.csv",
            MANIFEST, "_top.png", "_side.png", "_profile.png", "_returns.png", *PROFILE_SUFFIXES, "_waveforms.npz",
            "_pulses.npz")


def output_files(name: str) -> list[str]:
    return [name + s for s in SUFFIXES]


def existing_outputs(folder, name: str) -> list[str]:
    folder = Path(folder)
    return [f for f in output_files(name) if (folder / f).exists()]


def earlier_results(folder, name: str) -> list[str]:
    """The files of ``name`` in ``folder`` that a render replaces only with ``overwrite``: every output
    but the plan, since a lone plan is what ``mitsuforest plan`` leaves for a render to follow."""
    return [f for f in existing_outputs(folder, name) if f != name + PLAN]


def refuse_finished_render(folder, name: str) -> None:
    """Refuse to write a lone plan where a finished render of ``name`` is: the plan there is that
    render's, and replacing it would leave its points described by another plan."""
    if (Path(folder) / (name + MANIFEST)).exists():
        raise UserError(f"{folder} holds a finished render of '{name}' ({name}{MANIFEST}), whose plan this would "
                        "replace; plan into another folder (-o DIR), or render again with --overwrite")


def write_plan(folder, name: str, plan) -> Path:
    """Write ``NAME_plan.json`` into ``folder`` (``mitsuforest plan``), holding the render lock so that
    a render finishing meanwhile is not overwritten (see :func:`refuse_finished_render`)."""
    path = Path(folder) / (name + PLAN)
    with output_lock(folder, name):
        refuse_finished_render(folder, name)
        write_text(path, plan.to_json())
    return path


def check_output_folder(folder) -> None:
    """Refuse, before any work, an output folder that cannot be made or written: a file, a path under a
    file, or a folder this user cannot write (the nearest existing folder on the way is checked, by making
    and removing a folder in it: ``os.access`` says yes to root, also in ``/proc`` or ``/sys``)."""
    folder = Path(folder).absolute()
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    if not existing.is_dir():
        what = "is a file" if existing == folder else f"cannot be made: {existing} is a file"
        raise UserError(f"{folder}: the output folder {what}")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UserError(f"{folder}: the output folder cannot be written ({existing}: permission denied)")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".write-test-", dir=existing))
    except OSError as e:
        raise UserError(f"{folder}: the output folder cannot be written ({existing}: {e.strerror or e})") from None


@contextmanager
def output_lock(folder, name: str):
    """Hold ``.NAME.lock`` in ``folder`` while a render writes there (an advisory ``flock``); a second
    render of ``name`` into the same folder is refused with a :class:`UserError`. The folders it makes
    are removed again if the render leaves nothing in them (it failed)."""
    folder = Path(folder)
    made = [f for f in (folder, *folder.parents) if not f.exists()]      # deepest first
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f".{name}.lock"
    handle = open(path, "a+")  # noqa: SIM115 (held for the whole block)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if not _still_named(handle, path):   # a render that just finished unlinked it under us
            raise BlockingIOError
    except BlockingIOError:
        handle.close()
        raise UserError(f"{folder}: another render of '{name}' is writing here; wait for it to finish or "
                        "choose another output folder") from None
    try:
        yield
    finally:
        path.unlink(missing_ok=True)
        fcntl.flock(handle, fcntl.LOCK_UN)
        handle.close()
        _remove_if_empty(made)


def _remove_if_empty(folders: list[Path]) -> None:
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:         # not empty (another render's files, say): it and those above it stay
            return


def _still_named(handle, path: Path) -> bool:
    try:
        return os.stat(path).st_ino == os.fstat(handle.fileno()).st_ino
    except FileNotFoundError:
        return False


class Staging:
    """A hidden folder collecting one render's files until :meth:`commit` moves them into place.

    It is named ``.NAME.partial-RANDOM-HOST-PID``. Creating one removes the staging folders of renders
    of ``NAME`` that died on this host (killed, so they could not clean up), and no other: a render
    still running, here or on another host sharing the folder, keeps its own.
    """

    def __init__(self, folder, name: str):
        self.folder, self.name = Path(folder), name
        self.folder.mkdir(parents=True, exist_ok=True)
        for stale in self.stale_folders():
            shutil.rmtree(stale, ignore_errors=True)
        self.path = Path(tempfile.mkdtemp(prefix=self._prefix, suffix=f"-{owner_tag()}", dir=self.folder))

    @property
    def _prefix(self) -> str:
        return f".{self.name}.partial-"

    def stale_folders(self) -> list[Path]:
        """Staging folders of ``name`` in ``folder`` whose render has ended on this host."""
        ours = [p for p in self.folder.iterdir() if p.name.startswith(self._prefix) and p.is_dir()]
        # After the prefix: mkdtemp's random part (no "-" in it), then the owner tag.
        return [p for p in ours if owner_is_gone(p.name[len(self._prefix):].partition("-")[2])]

    def file(self, suffix: str) -> Path:
        return self.path / (self.name + suffix)

    def sync(self) -> None:
        """Flush every staged file (and folder) to disk (the slow part of :meth:`commit`, which may come
        first, where a signal can still stop it; the files are then flushed again at no cost)."""
        for p in self.path.rglob("*"):
            fsync_folder(p) if p.is_dir() else fsync_file(p)

    def commit(self, replaced: list[str] | None = None) -> list[Path]:
        """Remove the previous render's files (or the files and folders named in ``replaced``), then move
        the new ones in, the manifest last. Each file is flushed to disk before its rename, and the folder
        before the manifest's rename and after it, so a crash of the machine never leaves a renamed file
        without its content, nor the manifest without the files it lists."""
        self.sync()
        for old in existing_outputs(self.folder, self.name) if replaced is None else replaced:
            old = self.folder / old
            shutil.rmtree(old) if old.is_dir() and not old.is_symlink() else old.unlink(missing_ok=True)
        staged = sorted(self.path.iterdir(), key=lambda p: p.name.endswith("_manifest.json"))
        moved = []
        for p in staged:
            target = self.folder / p.name
            if p.name.endswith("_manifest.json"):
                fsync_folder(self.folder)
            os.replace(p, target)
            moved.append(target)
        fsync_folder(self.folder)
        self.path.rmdir()
        return moved

    def discard(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    def public_error(self, error: OSError) -> OSError:
        """``error`` naming the file it would have become (a staged file's final path), or the output
        folder when it names none (a failing ``write`` names no file)."""
        name = Path(error.filename) if error.filename else None
        if name is None:
            name = self.folder
        elif name.is_relative_to(self.path):
            name = self.folder / name.relative_to(self.path)
            name = name.with_name(name.name.split(TMP_MARK)[0])
        return OSError(error.errno, error.strerror or str(error), str(name))

    def commit_or_discard(self, write, replaced: list[str] | None) -> list[Path]:
        """Run ``write()`` (which fills :attr:`path`), then :meth:`commit` with Ctrl-C and SIGTERM held:
        on any failure or signal before, the staging folder is removed and nothing in :attr:`folder`
        changes (an :class:`OSError` then names the file it would have become)."""
        try:
            write()
            self.sync()
            try:
                with deferred_signals():     # never half the files in place
                    return self.commit(replaced)
            except KeyboardInterrupt as e:
                raise InterruptedAfterCommit(isinstance(e, Terminated)) from None
        except BaseException as e:
            self.discard()
            if isinstance(e, OSError):
                raise self.public_error(e) from e
            raise


TABLES = ("_volumes.csv", "_ids.csv", PLAN, "_trajectory.csv")   # what a render writes without its points


def write_tables(file, *, scene, plan, models) -> None:
    """Write the tables, plan and trajectory of a render (:data:`TABLES`), each atomically, to
    ``file(suffix)`` (a :class:`Staging`'s, or a dataset leg task's folder's)."""
    offset = scene.origin.offset
    write_volumes(file("_volumes.csv"), plan, models, offset)
    write_ids(file("_ids.csv"), plan, models, offset)
    write_text(file(PLAN), plan.to_json())
    write_trajectory(file("_trajectory.csv"), scene, plan)


def write_render_outputs(staging: Staging, *, scene, plan, models, writer) -> None:
    """Write the tables, plan, trajectory and quick looks of one render into ``staging``. The four
    pictures are drawn side by side in the writer's worker processes when it wrote its points with
    them (:attr:`PointWriter.pool`), while this process writes the tables; the side view's points go
    to its worker through a file in shared memory (:meth:`~.quicklook.SideTile.stored`)."""
    pool = writer.pool if scene.output.pictures else None
    with _side_tile_to_send(writer.side, pool) as side:
        pictures = []
        if scene.output.pictures:
            classes = [int(c) for c in np.flatnonzero(writer.classes)]
            pictures = [(write_top_figure, "_top.png", writer.top, writer.side.outline(), classes),
                        (write_tile_figure, "_side.png", side),
                        (write_profile_figure, "_profile.png", writer.counts),
                        (write_returns_figure, "_returns.png", writer.returns, writer.counts)]
        drawn = [pool.submit(draw_picture, draw, staging.file(suffix), *inputs)
                 for draw, suffix, *inputs in pictures] if pool else []
        try:
            write_tables(staging.file, scene=scene, plan=plan, models=models)
            if not pool:
                for draw, suffix, *inputs in pictures:
                    draw(staging.file(suffix), *inputs)
        finally:
            wait(drawn)                   # none draws into the staging folder, or reads the tile, after this
    for picture in drawn:
        picture.result()


@contextmanager
def _side_tile_to_send(tile, pool):
    """``tile`` itself without a ``pool`` of workers, else the tile stored in a file in shared memory for
    the block (:meth:`~.quicklook.SideTile.stored`)."""
    if pool is None:
        yield tile
        return
    size = sum(part.nbytes for part in tile.parts)
    with tempfile.TemporaryDirectory(prefix="mitsuforest-side-", dir=shared_folder(size)) as folder:
        yield tile.stored(Path(folder) / "side.npy")


def write_manifest(staging: Staging, manifest: dict) -> None:
    write_json(staging.file(MANIFEST), manifest, sort_keys=True)
