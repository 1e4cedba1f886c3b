"""The point writer's work on many cores: parts of each batch written and tallied in worker processes.

The writer's threads (:mod:`mitsuforest.threads`) share Python's lock with each other and with the scan,
and lazrs holds it while it compresses, so on a machine of many cores they use a few of them. With
worker processes each part of a batch is handled whole where it is sent: its heights above the ground,
its PCD records (written at their own offset in the file), its LAS records compressed into whole LAZ
chunks (a chunk's coder starts afresh, so chunks compressed apart and joined in order are the bytes of
one compressor), and its statistics. The writing process only copies each batch into shared memory,
hands out its parts and takes back, in order, the compressed chunks and the tallies, which a worker
leaves pickled over the part's own rows in shared memory rather than sending them through the pool's
pipe: the files are the bytes of the threaded writer, whatever the number of processes.

Parts are whole LAZ chunks of the file (:data:`~.las.LAZ_CHUNK` points): the rows of a batch past its
last whole chunk wait for the next batch, and the file's last part takes the rest.
"""

from __future__ import annotations

import collections
import os
import pickle
import shutil
import tempfile
import threading
from concurrent.futures import Future, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..pools import process_pool, usable_cores, worker_count
from ..threads import on_row_ranges, whole_number_variable
from .ground import copy_fields, fill_height, ground_surface, with_room_for_height
from .output_profiles import PROFILES
from .las import LAZ_CHUNK, HeaderSummary, compress_chunks, las_records
from .parts import georeference, tallies, write_at, write_pcd_rows

PROCESSES_VARIABLE = "MITSUFOREST_WRITER_PROCESSES"
MIN_CORES = 8              # from this many cores on, the writer uses processes by default
CHUNKS_PER_PART = 2        # LAZ chunks a worker handles at a time
SLOTS = 4                  # batches held in shared memory at once: one being copied, the rest in the workers' hands
FORMATS = {"pcd", "laz"}   # the point files written in worker processes; other outputs keep the threads


def writer_processes(cores: int | None = None) -> int:
    """Worker processes for the point writer: ``MITSUFOREST_WRITER_PROCESSES`` if set (0: the writer's
    threads), else one less than the cores this process may use from :data:`MIN_CORES` cores on, and 0
    below.

    :raises UserError: for a value that is not a whole number of at least 0.
    """
    processes = whole_number_variable(PROCESSES_VARIABLE, 0)
    if processes is not None:
        return processes
    cores = usable_cores() if cores is None else cores
    return worker_count(cores) if cores >= MIN_CORES else 0


def fits_processes(scene, keep: bool = False) -> bool:
    """Whether a render of ``scene`` can write its points in worker processes: its point files all of
    :data:`FORMATS`, no other ``output.profile`` than ours, and the points not kept in memory."""
    return not keep and scene.output.profile not in PROFILES and set(scene.output.formats) <= FORMATS


def start_processes(scene, keep: bool = False) -> None:
    """Start the worker processes that a render of ``scene`` will write with, if any, now: they start
    while the render plans and loads its scene."""
    processes = writer_processes() if fits_processes(scene, keep) else 0
    if processes:
        process_pool(processes)


@dataclass
class PartWork:
    """What a worker needs to write and tally its parts of a writer's batches (pickled once per writer,
    read by each worker once).

    :param pcd: the PCD file's path, its record dtype and where its records begin; None without a PCD.
    :param laz: the LAZ file's header and the sensor's intensity mapping; None without a LAZ.
    """

    offset: np.ndarray
    terrain: object
    pcd: tuple[str, np.dtype, int] | None
    laz: tuple | None
    top: object            # the writer's TopView, SideTile and ReturnCounts (empty: their settings)
    side: object
    counts: object
    tiles: np.ndarray      # (4, 2) spacing tiles' corners
    warm_pictures: bool = False    # ready each worker to draw the render's pictures (start_warming)
    _cache: dict = field(default_factory=dict, repr=False)

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_cache"}

    def __setstate__(self, state):
        self.__dict__.update(state, _cache={})

    def write(self, scanned: np.ndarray, first_row: int) -> PartResult:
        """Rows ``scanned`` (local frame, POINT_DTYPE), the file's rows from ``first_row`` on: written to the
        PCD at their offset, compressed as LAZ chunks, and their statistics."""
        if "ground" not in self._cache:
            self._cache["ground"] = ground_surface(self.terrain)
        points = fill_height(scanned, with_room_for_height(scanned), self._cache["ground"])
        geo = georeference(points, self.offset)
        if self.pcd:
            path, record, start = self.pcd
            if "pcd" not in self._cache:
                self._cache["pcd"] = os.open(path, os.O_WRONLY)
            write_pcd_rows(self._cache["pcd"], path, record, start + first_row * record.itemsize, geo)
        laz = None
        if self.laz:
            header, intensity = self.laz
            records = las_records(header, geo, intensity=intensity)
            laz = (*compress_chunks(header, records), HeaderSummary.of(records, header.point_format))
        return PartResult(len(points), tallies(points, self.counts, self.side, self.tiles), self.top.part(points), laz)

    def close(self) -> None:
        if "pcd" in self._cache:
            os.close(self._cache.pop("pcd"))


@dataclass
class PartResult:
    rows: int
    tallies: tuple
    top: tuple
    laz: tuple | None      # chunks' bytes, chunk table, header summary


_WORKS: collections.OrderedDict = collections.OrderedDict()     # a worker's PartWork by path


def write_part(work_path: str, slot_path: str, dtype: np.dtype, start: int, stop: int,
               first_row: int) -> PartResult | tuple[int, int]:
    """A worker's task: rows ``start:stop`` of the batch slot ``slot_path`` through the writer's
    :class:`PartWork` stored at ``work_path``; the :class:`PartResult` left in their place (:func:`placed`)."""
    work = _WORKS.get(work_path)
    if work is None:
        work = _WORKS[work_path] = pickle.loads(Path(work_path).read_bytes())
        while len(_WORKS) > 2:
            _WORKS.popitem(last=False)[1].close()
        if work.warm_pictures:
            start_warming()
    rows = np.memmap(slot_path, dtype, "r", offset=start * dtype.itemsize, shape=(stop - start,))
    part = work.write(np.asarray(rows), first_row)       # holds copies: the rows are free once it returns
    return placed(part, slot_path, start * dtype.itemsize, (stop - start) * dtype.itemsize)


def placed(part: PartResult, path: str, offset: int, size: int) -> PartResult | tuple[int, int]:
    """``part`` pickled into the ``size`` bytes at ``offset`` of the file ``path`` (its rows of the batch
    in shared memory, read already), for the writing process to read there (:func:`taken_back`): the
    pickle's (offset, byte count); or ``part`` itself when its pickle does not fit, to be sent back
    through the pool's pipe.

    The pipe costs the writing process a copy in 64 kB reads, each taking Python's lock again, while it
    scans: its LAZ chunks, pixels and side-view points are about 18 bytes a point (the open scene's thin
    beam), and a row has 72.
    """
    data = pickle.dumps(part, protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) > size:
        return part
    fd = os.open(path, os.O_WRONLY)
    try:
        write_at(fd, np.frombuffer(data, np.uint8), offset)
    finally:
        os.close(fd)
    return offset, len(data)


def taken_back(result: PartResult | tuple[int, int], batch: np.ndarray) -> PartResult:
    """The :class:`PartResult` of a :func:`write_part` task, read from ``batch`` (the mapped bytes of its
    batch's file) when it was :func:`placed` there."""
    if isinstance(result, PartResult):
        return result
    offset, size = result
    return pickle.loads(memoryview(batch)[offset:offset + size])


_WARMING: list[threading.Thread] = []     # this worker's warm-up of the pictures, once started


def start_warming() -> None:
    """Ready this worker to draw pictures (:func:`~.figures.warm_up`: 0.5 s) in a thread of its own, once
    a process, while it writes parts: the pictures of a render are drawn in the workers when its points
    are all written, and a cold worker took 0.56 s for the side view instead of 0.23 s (a 2-core Xeon)."""
    if not _WARMING:
        _WARMING.append(threading.Thread(target=_warm_up, name="mitsuforest-warm-pictures", daemon=True))
        _WARMING[0].start()


def _warm_up() -> None:
    from .figures import warm_up
    try:
        warm_up()
    except Exception:        # noqa: BLE001  (a picture that fails for this reason raises it where it is drawn)
        pass


def draw_picture(draw, path, *inputs) -> None:
    """A worker's task: ``draw(path, *inputs)`` once this worker's warm-up, if started, is done (the two
    never draw at once)."""
    for thread in _WARMING:
        thread.join()
    draw(path, *inputs)


def shared_folder(size: int) -> str:
    """A folder for ``size`` bytes of batch slots: ``/dev/shm`` when it has room for them twice over
    (shared memory that no disk writes back), else the temporary folder."""
    try:
        shm = os.statvfs("/dev/shm")
        if shm.f_bavail * shm.f_frsize > 2 * size:
            return "/dev/shm"
    except OSError:
        pass
    return tempfile.gettempdir()


def _copy_rows(points: np.ndarray, out: np.ndarray, start: int, stop: int) -> None:
    """Rows ``start:stop`` of ``out[:] = points``. A batch's copy into shared memory is made a row range
    a host thread (:func:`~mitsuforest.threads.on_row_ranges`): one thread copies at about a third of
    what the memory gives (10.5 ms a million points on a 2-core Xeon, 5.5 on both cores), and on a GPU's
    host it is the writing process's own work on every point."""
    copy_fields(points[start:stop], out[start:stop])


class ProcessParts:
    """A :class:`~.stream.PointWriter`'s batches handed to worker processes (see module docstring);
    what comes back is merged into the writer and its LAZ stream in the file's order.

    :param writer: the writer whose statistics and LAZ stream take the results.
    :param work: what the workers need (:class:`PartWork`).
    """

    def __init__(self, writer, work: PartWork, processes: int):
        self.writer = writer
        self.pool = process_pool(processes)
        self.chunked = work.laz is not None
        self._folder = Path(tempfile.mkdtemp(prefix="mitsuforest-writer-", dir=shared_folder(SLOTS * 200 << 20)))
        self._work_path = self._folder / "work.pickle"
        self._work_path.write_bytes(pickle.dumps(work))
        self._pending: collections.deque = collections.deque()   # (slot path, [futures]) in the file's order
        self._free: dict[Path, np.memmap] = {}     # batch files not in the workers' hands
        self._busy: dict[Path, np.memmap] = {}
        self._held = None            # rows waiting for a whole chunk
        self._sent = 0               # the file's rows handed out so far
        self._made = 0

    def add(self, points: np.ndarray) -> None:
        """Hand out the whole chunks of ``points`` (and of the rows held from earlier batches)."""
        held = self._held if self._held is not None else points[:0]
        rows = len(held) + len(points)
        whole = (self._sent + rows) // LAZ_CHUNK * LAZ_CHUNK - self._sent if self.chunked else rows
        if whole <= 0:
            self._held = np.concatenate([held, points])
            return
        self._collect_done()
        slot, batch = self._slot(rows, points.dtype)
        copy_fields(held, batch[:len(held)])
        on_row_ranges(len(points), _copy_rows, points, batch[len(held):])
        self._held = np.array(batch[whole:])
        self._send(slot, points.dtype, whole)

    def _send(self, slot: Path, dtype: np.dtype, rows: int) -> None:
        step = CHUNKS_PER_PART * LAZ_CHUNK
        tasks = [self.pool.submit(write_part, str(self._work_path), str(slot), dtype, start,
                                  min(start + step, rows), self._sent + start)
                 for start in range(0, rows, step)]
        self._pending.append((slot, tasks))
        self._sent += rows

    def _slot(self, rows: int, dtype: np.dtype) -> tuple[Path, np.ndarray]:
        """``rows`` records in a file in shared memory, once a slot is free (the oldest batch's results
        taken back): a free file of the size or larger, mapped once, else a new one."""
        while len(self._pending) >= SLOTS:
            self._collect(self._pending.popleft())
        size = rows * dtype.itemsize
        fits = [path for path, mapped in self._free.items() if len(mapped) >= size]
        if fits:
            path = min(fits, key=lambda p: len(self._free[p]))
        else:
            if len(self._free) >= SLOTS:                        # the smallest free file makes room
                smallest = min(self._free, key=lambda p: len(self._free[p]))
                del self._free[smallest]
                smallest.unlink()
            self._made += 1
            path = self._folder / f"batch-{self._made}"
            self._free[path] = np.memmap(path, np.uint8, "w+", shape=(max(size, 1),))
        mapped = self._free.pop(path)
        self._busy[path] = mapped
        return path, mapped[:size].view(dtype)

    def _collect_done(self) -> None:
        while self._pending and all(t.done() for t in self._pending[0][1]):
            self._collect(self._pending.popleft())

    def _collect(self, pending: tuple[Path, list[Future]]) -> None:
        slot, tasks = pending
        try:
            for task in tasks:
                self._merge(taken_back(task.result(), self._busy[slot]))
        finally:
            for task in tasks:
                task.cancel()
            wait(tasks)          # after a failed part, none of the others still writes into the slot or a file
            self._free[slot] = self._busy.pop(slot)

    def _merge(self, part: PartResult) -> None:
        self.writer.merge_part(part.rows, part.tallies)
        self.writer.top.merge(part.top)
        if part.laz:
            self.writer.laz_stream.write_chunks(*part.laz)

    def close(self) -> None:
        """Hand out the rows held back (the file's last chunk) and take back every result."""
        if self._held is not None and len(self._held):
            slot, batch = self._slot(len(self._held), self._held.dtype)
            copy_fields(self._held, batch)
            self._held = None
            self._send(slot, batch.dtype, len(batch))
        while self._pending:
            self._collect(self._pending.popleft())
        self._remove_folder()

    def abort(self) -> None:
        """Drop what is not yet written; wait for the parts being written (none writes after this)."""
        tasks = [task for _, slot_tasks in self._pending for task in slot_tasks]
        for task in tasks:
            task.cancel()
        wait(tasks)
        self._pending.clear()
        self._remove_folder()

    def _remove_folder(self) -> None:
        self._free.clear()
        self._busy.clear()
        shutil.rmtree(self._folder, ignore_errors=True)

