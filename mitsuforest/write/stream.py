"""Streaming point output: each scan batch goes straight to the PCD and LAS files.

Memory stays bounded by the batch size however many points a survey makes. Statistics (counts,
classes, returns, spacing) and the quick-look rasters are accumulated batch by batch.

A batch is cut into row ranges that the writer's threads (:mod:`mitsuforest.threads`) handle side
by side: each tallies its statistics, georeferences its points, writes its PCD records at their own
offset in the file and packs its LAS records into their own rows; the LAS records are then
compressed in file order. The files are the same bytes whatever the number of threads. On a machine of
many cores the parts go to worker processes instead (:mod:`.processes`), with the same bytes.
"""

from __future__ import annotations

import numpy as np

from .. import seeds
from ..fields import POINT_DTYPE, POINT_FORMATS, pcd_dtype
from ..threads import Workers, row_ranges, writer_threads
from .atomic import naming_errors
from .closing import Closing
from .copc import CopcStream
from .ground import fill_height, ground_surface, with_room_for_height
from .las import LasStream, las_records
from .pcd import COUNT_DIGITS, pcd_header
from .output_profiles import PROFILES
from .parts import SPACING_TILE, georeference, tallies, write_pcd_rows
from .processes import PartWork, ProcessParts, fits_processes, writer_processes
from .profile import ReturnCounts
from .quicklook import SideTile, TopView

SPACING_QUERIES = 10_000  # points of a tile drawn to ask for their nearest neighbour (the tree holds them all)


class PointWriter(Closing):
    """Receives local-frame points batch by batch (:meth:`add`) and writes georeferenced files; closing,
    aborting and refusing batches once closed as :class:`~.closing.Closing`.

    :param terrain: the plan's :class:`~mitsuforest.plan.terrain.Terrain`, for heights above the ground.
    :param threads: the writer's threads (default: :func:`~mitsuforest.threads.writer_threads`, the
        cores this process may use, or ``MITSUFOREST_WRITER_THREADS``); 1 writes in the calling thread
        alone.
    :param stems: sorted object ids of the stem components, for an ``output.profile`` that tells stems from
        branches (:func:`~.output_profiles.stem_ids`).
    :param processes: worker processes for the points of a render that writes PCD and LAZ alone, kept
        nowhere else (default: :func:`~.processes.writer_processes`, none below 8 cores); 0: the threads.
    :param warm_pictures: with worker processes, ready them to draw the pictures while the points come
        (:func:`~.processes.start_warming`): worth its CPU when the scan leaves the host's cores idle.
    """

    def __init__(self, staging, scene: dict, keep: bool = False, terrain=None, threads: int | None = None,
                 stems=(), processes: int | None = None, warm_pictures: bool = False):
        self.threads = writer_threads() if threads is None else threads
        self.offset = np.asarray(scene.origin.offset, np.float64)
        self.area = scene.area.size
        formats = scene.output.formats if staging else []
        profile = PROFILES.get(scene.output.profile) if staging else None     # None: ours only
        processes = writer_processes() if processes is None else processes
        self._processes = processes if staging and fits_processes(scene, keep) else 0
        self._pcd_file = open(staging.file(POINT_FORMATS["pcd"]), "wb") if staging and "pcd" in formats else None  # noqa: SIM115
        self._pcd_end = 0          # where the next batch's records go in the PCD file
        self._las = [LasStream(staging.file(POINT_FORMATS[f]), self.offset, scene.origin.crs, threads=self.threads,
                               intensity=scene.sensor.intensity, chunks=self._processes > 0)
                     for f in ("las", "laz") if f in formats]
        self._workers = Workers(self.threads)
        self._others = []      # written whole batch by batch, after the threaded LAS and PCD records
        if "copc" in formats:                        # spooled, then built into an octree on close
            self._others.append(CopcStream(staging.file(POINT_FORMATS["copc"]), self.offset, scene.origin.crs,
                                           scene.sensor.intensity))
        if profile:
            self._others.append(profile.stream(staging.file(profile.suffix), self.offset, scene.origin.crs, stems,
                                               scene.sensor.intensity))
        self._kept = [] if keep else None
        self.count = 0
        self.classes = np.zeros(256, np.int64)
        self.returns = np.zeros(256, np.int64)
        self.top = TopView(self.area)
        self.side = SideTile(self.area)
        self.counts = ReturnCounts(terrain, self.area)      # profile and return charts, realism table
        self._ground = ground_surface(terrain)              # every point's height_above_ground
        rng = seeds.rng(scene.seed, "spacing-tiles")
        corner = [rng.uniform(0, max(s - SPACING_TILE, 0), 4) for s in self.area]
        self._tiles = np.column_stack(corner)
        self._tile_points = [[] for _ in self._tiles]
        self._seed = scene.seed
        self.dtype = None
        self._terrain = terrain
        self._warm_pictures = warm_pictures
        self._parts: ProcessParts | None = None

    @property
    def pool(self):
        """The worker processes' pool when the points were written with them, else None."""
        return self._parts.pool if self._parts else None

    @property
    def laz_stream(self) -> LasStream:
        return self._las[0]

    def add(self, points: np.ndarray) -> None:
        """Add a batch of local-frame points (POINT_DTYPE); each file gets ``height_above_ground`` too.
        Returns once it is written (LAZ: once it is compressed or waits for whole chunks)."""
        self._refuse_if_closed()
        self._add(points)

    def _add(self, points: np.ndarray) -> None:
        batch = with_room_for_height(points)     # the scan's fields and height_above_ground, filled by _part
        if self.dtype is None and self._pcd_file:
            self._pcd_record = pcd_dtype(batch.dtype, local=not np.any(self.offset))
            header = pcd_header(self._pcd_record, 0, COUNT_DIGITS).encode("ascii")
            with naming_errors(self._pcd_file.name):
                self._pcd_file.write(header)
                self._pcd_file.flush()       # the records are written at their offsets, past the buffer
            self._pcd_end = len(header)
        if self.dtype is None and self._processes:
            self._parts = ProcessParts(self, self._part_work(), self._processes)
        self.dtype = batch.dtype
        if len(points) == 0:
            return
        if self._parts:
            self._parts.add(points)
            return
        records = [las.reserve(len(points)) for las in self._las]
        tasks = [self._workers.submit(self.top.add, points)]       # in order: a pixel keeps its last highest point
        try:
            for start, stop in row_ranges(len(points), self.threads):
                tasks.append(self._workers.submit(self._part, points, batch, start, stop, records))
            tallies = self._workers.results(tasks)[1:]
            for las in self._las:
                las.commit(len(points))
        finally:
            Workers.finish(tasks)          # none is left writing when an error is raised
        for (start, stop), tally in zip(row_ranges(len(points), self.threads), tallies):
            self.merge_part(stop - start, tally)
        if self._pcd_file:
            self._pcd_end += len(points) * self._pcd_record.itemsize
        if self._others or self._kept is not None:
            geo = georeference(batch, self.offset)
            for stream in self._others:
                stream.write(geo)
            if self._kept is not None:
                self._kept.append(geo)

    def merge_part(self, rows: int, tally: tuple) -> None:
        """Add the statistics of a part of ``rows`` points (:func:`~.parts.tallies`)."""
        classes, returns, counts, side, tiles = tally
        self.classes += classes
        self.returns += returns
        self.counts.merge(counts)
        self.side.parts.append(side)
        for bucket, xyz in zip(self._tile_points, tiles):
            bucket.append(xyz)
        self.count += rows

    def _part_work(self) -> PartWork:
        """What the worker processes write and tally parts with (the batches' PCD records from the
        header's end on)."""
        pcd = (self._pcd_file.name, self._pcd_record, self._pcd_end) if self._pcd_file else None
        laz = (self._las[0].header, self._las[0].intensity) if self._las else None
        return PartWork(self.offset, self._terrain, pcd, laz, TopView(self.area), SideTile(self.area),
                        ReturnCounts(self._terrain, self.area), self._tiles, self._warm_pictures)

    def _part(self, scanned: np.ndarray, batch: np.ndarray, start: int, stop: int, records: list[np.ndarray]) -> tuple:
        """Rows ``start:stop`` of a batch: copied from the ``scanned`` points into ``batch`` with their
        height above the ground, written to the PCD, packed into each LAS file's ``records``, and their
        statistics, returned for :meth:`add` to merge in order."""
        points = fill_height(scanned[start:stop], batch[start:stop], self._ground)
        geo = georeference(points, self.offset)
        if self._pcd_file:
            write_pcd_rows(self._pcd_file.fileno(), self._pcd_file.name, self._pcd_record,
                           self._pcd_end + start * self._pcd_record.itemsize, geo)
        for las, rows in zip(self._las, records):
            las_records(las.header, geo, rows[start:stop], las.intensity)
        return tallies(points, self.counts, self.side, self._tiles)

    def _finish(self) -> None:
        """Finish the files: the PCD header is written once the point count is known."""
        if self._pcd_file and self.dtype is None:
            self._add(np.zeros(0, POINT_DTYPE))          # no batch came: the header of no points
        if self._parts:
            self._parts.close()
        self._workers.close()
        for las in (*self._las, *self._others):
            las.close()
        if self._pcd_file:
            with naming_errors(self._pcd_file.name):
                self._pcd_file.seek(0)                 # the counts, now known, in the header's padded fields
                self._pcd_file.write(pcd_header(self._pcd_record, self.count, COUNT_DIGITS).encode("ascii"))
                self._pcd_file.close()

    def _discard(self) -> None:
        """Close whatever is still open (after a failure, possibly inside :meth:`close`)."""
        if self._parts:
            self._parts.abort()
        self._workers.close()
        for las in (*self._las, *self._others):
            las.abort()
        if self._pcd_file and not self._pcd_file.closed:
            self._pcd_file.close()

    @property
    def points(self) -> np.ndarray | None:
        """All points, georeferenced, when the writer was made with ``keep=True``."""
        if self._kept is None:
            return None
        return np.concatenate(self._kept) if self._kept else np.zeros(0, self.dtype)

    def statistics(self) -> dict:
        """Density over the plot, mean nearest-neighbour spacing, class and returns counts."""
        plot_area = float(self.area[0] * self.area[1])
        spacings, rng = [], seeds.rng(self._seed, "spacing-queries")
        for bucket in self._tile_points:
            xyz = np.vstack(bucket) if bucket else np.zeros((0, 3))
            if len(xyz) > 1:
                spacings.append(nearest_distances(xyz, spacing_queries(len(xyz), rng)))
        return {
            "points": int(self.count),
            "density_per_m2": self.count / plot_area if plot_area else 0.0,
            "classes": {int(k): int(v) for k, v in enumerate(self.classes) if v},
            "pulses_with_returns": int(self.returns.sum()),
            "returns_histogram": {int(k): int(v) for k, v in enumerate(self.returns) if v},
            "mean_spacing_m": float(np.concatenate(spacings).mean()) if spacings else None,
        }


def spacing_queries(n: int, rng: np.random.Generator, most: int = SPACING_QUERIES) -> np.ndarray | None:
    """Rows of a tile's n points that ask for their nearest neighbour: ``most`` of them drawn at random
    without replacement, in increasing order, or None (all) when there are no more than that. A random
    draw, not every k-th point, which could fall in step with the returns of each pulse."""
    if n <= most:
        return None
    return np.sort(rng.choice(n, most, replace=False))


def nearest_distances(xyz: np.ndarray, rows: np.ndarray | None = None, cell: float = 0.25) -> np.ndarray:
    """(m,) the distance from each of the points ``xyz[rows]`` (all n when ``rows`` is None) to its
    nearest other point of ``xyz`` (n, 3), n >= 2.

    The tree holds every point, so that a sample of queries does not widen the spacing as thinning the
    points would. The points go into the k-d tree and its queries in the order of ``cell``-sized squares
    (by y, then x), so that neighbours lie near each other in memory: half the time of the scan's order.
    Each distance is the same number in any order (that of the same pair of points, computed alike).
    """
    from scipy.spatial import cKDTree
    square = np.floor(xyz[:, :2] / cell).astype(np.int64)
    order = np.lexsort((square[:, 0], square[:, 1]))
    tree = cKDTree(xyz[order], balanced_tree=False)
    asked = order
    if rows is not None:
        asking = np.zeros(len(xyz), bool)
        asking[rows] = True
        asked = order[asking[order]]             # the rows asking, in the squares' order
    distances = np.empty(len(xyz))
    distances[asked] = tree.query(xyz[asked], k=2)[0][:, 1]
    return distances if rows is None else distances[rows]
