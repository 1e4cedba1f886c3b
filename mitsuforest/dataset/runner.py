"""The client side of ``mitsuforest dataset``: connect to Dask, submit the plots, follow them, write the
index, the splits and the manifest.

All scheduling is Dask's: one future per plot (or per range of a large plot's legs, then one
merging them, the tile tasks and the record's), retried on another worker when a worker dies (``retries``). With no scheduler
address an embedded ``LocalCluster`` (one process per worker, one Dask thread each) starts and
stops with the command.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..interrupts import StoppedWithWorkKept, Terminated, deferred_signals
from ..write import check_output_folder
from . import files, tasks
from .spec import Dataset, load_dataset
from .tiles import tile_grid

RETRIES = 2            # a task is tried this many more times after failing (a dead worker is not counted)
INDEX_EVERY_S = 10.0   # the index is rewritten at most this often while plots finish
CONNECT_TIMEOUT = "10s"


def run_dataset(dataset, output_dir=None, workers: int | None = None, scheduler: str | None = None,
                threads: int | None = None, progress: bool = True, log=print) -> dict:
    """Render every plot of a dataset (a file or a :class:`~.spec.Dataset`) on Dask and write the
    index, splits and manifest into ``output_dir`` (default ``out/<dataset name>``).

    Plots already finished and undamaged are kept; the rest are (re)done. Returns the manifest.

    :param workers: worker processes of the embedded LocalCluster (default: one per core).
    :param scheduler: the address of a running Dask scheduler (``tcp://HOST:8786``) instead.
    :param threads: Dr.Jit threads per worker process (default: cores / workers on the LocalCluster;
        all cores of its machine on a scheduler's workers, right for one worker process per machine).
    :raises UserError: bad input or an unreachable scheduler, before anything is written.
    """
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset)
    root = Path(output_dir or Path("out", dataset.name)).absolute()
    check_output_folder(root)
    if workers is not None and workers < 1:
        raise UserError(f"--workers: must be >= 1, got {workers}")
    if workers is not None and scheduler:
        raise UserError("--workers: sets the embedded LocalCluster's size; with --scheduler the cluster's own "
                        "workers are used")
    if threads is not None and threads < 1:
        raise UserError(f"--threads: must be >= 1, got {threads}")
    splits = files.assign_splits([p.name for p in dataset.plots], dataset.splits, dataset.seed)
    records = []
    client, cluster, default_threads = _connect(scheduler, workers)
    for note in _empty_splits(splits, dataset):
        log(f"note: {note}")
    threads = threads or default_threads
    start = time.perf_counter()
    try:
        for plot in dataset.plots:
            scene = plot.scene.with_({"output.dir": str(files.plot_folder(root, plot.name))})
            files.write_scene_file(files.scene_file(root, plot.name), scene)
        files.write_json(root / "splits.json", splits)
        failures = _run(client, dataset, str(root), threads, splits, progress, records)
    except KeyboardInterrupt as e:
        _stop(client, cluster)
        raise _interrupted(root, dataset, records, splits, isinstance(e, Terminated)) from None
    finally:
        _stop(client, cluster)
    manifest = _manifest(dataset, records, failures, time.perf_counter() - start, scheduler,
                         workers if scheduler is None else None)
    files.write_index(root, records, dataset.varied, splits)
    files.write_json(root / "dataset_manifest.json", manifest)
    done = len(records)
    log(f"dataset {dataset.name}: {done}/{len(dataset.plots)} plots ({sum(r.get('skipped', False) for r in records)} "
        f"already done), {sum(r['points'] for r in records):,} points, "
        f"{sum(len(r.get('tiles', [])) for r in records)} tiles in {manifest['seconds']:.1f} s -> {root}")
    if failures:
        first = next(iter(failures.items()))
        raise DatasetIncomplete(f"{len(failures)} of {len(dataset.plots)} plots failed (first: {first[0]}: "
                                f"{first[1]}); the index lists the {done} finished. Run the same command again "
                                "to retry them")
    return manifest


def _empty_splits(splits: dict, dataset: Dataset) -> list[str]:
    """Why a split with a share holds no plot (too few plots for it), one sentence per split."""
    n = len(dataset.plots)
    return [f"split '{key}' ({ratio:.1%}) holds none of the {n} plots: {n} plots at {ratio:.1%} make "
            f"{n * ratio:.2f} of one (each block of {files.SPLIT_BLOCK} plots gets its share, rounded)"
            for key, ratio in dataset.splits.items() if ratio > 0 and not splits[key]]


class DatasetIncomplete(UserError):
    """Some plots failed: the others are finished and indexed."""

    exit_code = 1


def _stop(client, cluster) -> None:
    """Close the client and the embedded cluster (again: a no-op), with Ctrl-C and SIGTERM held.

    Dask's own loggers are silenced first and left so: LocalCluster's ``silence_logs`` ends with the
    cluster, and closing connections to workers that a signal stopped logs tracebacks (``Batched Comm
    Closed``) on the command's stderr, after the cluster, on Dask's event-loop thread."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    with deferred_signals(ignore=True):
        client.close()
        if cluster is not None:
            cluster.close()


def _interrupted(root: Path, dataset: Dataset, records: list, splits, terminated: bool) -> StoppedWithWorkKept:
    """Index every plot finished so far, those whose record came after the last result the client took
    included, and say how many are kept."""
    with deferred_signals(ignore=True):
        taken = {r["plot"] for r in records}
        late = [files.valid_record(root, p.name) for p in dataset.plots if p.name not in taken]
        records = records + [_with_values(r, dataset) for r in late if r is not None]
        if (root / "splits.json").exists():      # else stopped before the dataset's first file
            files.write_index(root, records, dataset.varied, splits)
    kept = (f"{len(records)} of {len(dataset.plots)} plots finished and kept, listed in {root / 'index.csv'}"
            if records else f"none of the {len(dataset.plots)} plots finished")
    return StoppedWithWorkKept(f"{kept}. Run the same command again to render the rest", terminated)


def _connect(scheduler: str | None, workers: int | None):
    """A Dask client: to ``scheduler``, or to a new LocalCluster. Returns (client, cluster or None,
    Dr.Jit threads per worker or None)."""
    from dask.distributed import Client, LocalCluster
    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT), None, None
        except (OSError, TimeoutError, ValueError) as e:
            raise UserError(f"--scheduler: cannot reach the Dask scheduler at {scheduler} ({e})") from None
    cores = os.cpu_count() or 1
    workers = workers or cores
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                           scheduler_kwargs={"dashboard_address": ":0"},   # no warning when port 8787 is taken
                           silence_logs=logging.CRITICAL,   # a failed task is the client's to report, in one line
                           preload=["mitsuforest.interrupts"])   # workers leave Ctrl-C to the client
    return Client(cluster), cluster, max(1, cores // workers)


def _run(client, dataset: Dataset, root: str, threads, splits, progress: bool, records: list) -> dict:
    """Submit every plot and follow them to the end, appending their records to ``records``; returns
    ``{plot: failure}``."""
    if dataset.legs_per_task:
        futures, kept = _submit_split_plots(client, dataset, root, threads)
        records += [_with_values({**r, "skipped": True}, dataset) for r in kept]
    else:
        futures = _submit_plots(client, dataset, root, threads)
    bars = _Bars(progress, len(dataset.plots), sum(_pulses(p.scene) for p in dataset.plots))
    bars.plot(len(records), sum(r["pulses"] for r in records))
    try:
        return _follow(futures, records, dataset, root, splits, bars)
    finally:
        bars.close()


def dataset_token(dataset: Dataset, root: str) -> str:
    """A short hash of the dataset (every value of its file, defaults filled) and its output folder: part of
    every task key, so that two datasets on one shared scheduler never share a key (their plots have the same
    names), while a re-run of the same dataset keeps its keys."""
    text = json.dumps([dataset.resolved, dataset.file, str(root)], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


NUMBERED = ("legs", "tiles")   # kinds of task whose key ends in a number (their first leg or tile)


def task_key(kind: str, token: str, plot: str, *rest) -> str:
    """A Dask key, ``KIND-TOKEN-PLOT[-REST...]`` (kind: ``plot``, ``check``, ``legs``, ``merge`` or ``tiles``);
    a plot's record comes from its ``plot`` task."""
    return "-".join([kind, token, plot, *map(str, rest)])


def _plot_of(key: str) -> str:
    """The plot a task key names (a plot's name may hold ``-``; the token never does)."""
    kind, _, rest = key.partition("-")
    plot = rest.partition("-")[2]
    return plot.rsplit("-", 1)[0] if kind in NUMBERED else plot


def _submit_plots(client, dataset: Dataset, root: str, threads) -> list:
    """One task per plot; returns the futures."""
    token = dataset_token(dataset, root)
    return [client.submit(tasks.render_plot, root, p.name, dataset.tiles, threads, key=task_key("plot", token, p.name),
                          retries=RETRIES, pure=False) for p in dataset.plots]


def _submit_split_plots(client, dataset: Dataset, root: str, threads):
    """Per plot not finished yet: one task per ``legs_per_task`` legs; when they are done (Dask runs the
    next tasks then), one merging them into the plot's files unless ``tiles.plot_files`` is false, and
    with tiles as many tile tasks as leg tasks, each writing a run of the plot's tiles from the parts;
    then one writing the record. Returns (futures, records of the finished plots)."""
    token = dataset_token(dataset, root)
    checks = client.gather([client.submit(tasks.check_plot, root, p.name, key=task_key("check", token, p.name),
                                          pure=False) for p in dataset.plots])
    tiles = dataset.tiles
    futures, kept = [], []
    for plot, record in zip(dataset.plots, checks):
        if record is not None:
            kept.append(record)
            continue
        legs = len(_legs(plot.scene))
        parts = [client.submit(tasks.scan_legs, root, plot.name, first, min(first + dataset.legs_per_task, legs),
                               threads, tiles, key=task_key("legs", token, plot.name, first), retries=RETRIES,
                               pure=False)
                 for first in range(0, legs, dataset.legs_per_task)]
        merged = None
        if tiles is None or tiles.plot_files:
            merged = client.submit(tasks.merge_plot, root, plot.name, parts, threads,
                                   key=task_key("merge", token, plot.name), retries=RETRIES, pure=False)
        groups = [client.submit(tasks.write_tile_group, root, plot.name, parts, tiles, first, stop, threads,
                                key=task_key("tiles", token, plot.name, first), retries=RETRIES, pure=False)
                  for first, stop in tile_groups(plot.scene.area.size, tiles, len(parts))]
        futures += [*parts, *([merged] if merged else []), *groups,
                    client.submit(tasks.finish_split_plot, root, plot.name, parts, merged, groups,
                                  key=task_key("plot", token, plot.name), retries=RETRIES, pure=False)]
    return futures, kept


def tile_groups(area_size, tiles, count: int) -> list[tuple[int, int]]:
    """``count`` runs ``(first, stop)`` of a plot's tile numbers, as even as can be (fewer when there are
    fewer tiles; none without tiles)."""
    if tiles is None:
        return []
    nx, ny = tile_grid(area_size, tiles.size)
    bounds = np.linspace(0, nx * ny, min(count, nx * ny) + 1).round().astype(int)
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))


def _follow(futures, records: list, dataset: Dataset, root: str, splits, bars) -> dict:
    """Collect results as they come (records appended to ``records``); a failed task fails its plot only
    (its other tasks are cancelled). The index is rewritten every INDEX_EVERY_S. Returns the failures."""
    from dask.distributed import as_completed
    failures, last_index = {}, time.perf_counter()
    plot_of = {f.key: _plot_of(f.key) for f in futures}
    for future in as_completed(futures):
        name = plot_of[future.key]
        if name in failures or future.status == "cancelled":
            continue
        try:
            result = future.result()
        except Exception as e:  # noqa: BLE001 (a worker's error ends this plot only; reported at the end)
            failures[name] = str(e) if isinstance(e, UserError) else f"{type(e).__name__}: {e}"
            for f in futures:
                if plot_of[f.key] == name and not f.done():
                    f.cancel()
            bars.plot(1, 0)
            continue
        if future.key.startswith("legs-"):
            bars.pulses(result["emitted"])
        if not future.key.startswith("plot-"):
            continue
        records.append(_with_values(result, dataset))
        bars.plot(1, 0 if dataset.legs_per_task else result["pulses"])   # a split plot's legs counted its pulses
        if time.perf_counter() - last_index > INDEX_EVERY_S:
            files.write_index(root, records, dataset.varied, splits)
            last_index = time.perf_counter()
    return failures


def _with_values(record: dict, dataset: Dataset) -> dict:
    return {**record, "values": dataset.values_of(record["plot"])}


def _legs(scene) -> list:
    """A plot's flight legs (their number and durations do not depend on their height)."""
    from ..plan.flight import flight_legs
    return flight_legs(scene.area.size, scene.survey, 0.0)


def _pulses(scene) -> int:
    """Time slots of a plot's survey."""
    return sum(leg.pulse_count(scene.pulse_frequency) for leg in _legs(scene))


class _Bars:
    """Two progress bars on the client: plots finished, and pulses flown."""

    def __init__(self, enabled: bool, plots: int, pulses: int):
        self._bars = None
        if enabled:
            from tqdm import tqdm
            self._bars = (tqdm(total=plots, desc="plots", unit=" plots", position=0, dynamic_ncols=True),
                          tqdm(total=pulses, desc="pulses", unit=" pulses", unit_scale=True, position=1,
                               dynamic_ncols=True))

    def plot(self, plots: int, pulses: int) -> None:
        if self._bars:
            self._bars[0].update(plots)
            self.pulses(pulses)

    def pulses(self, pulses: int) -> None:
        if self._bars and pulses:
            self._bars[1].update(pulses)

    def close(self) -> None:
        if self._bars:
            for bar in self._bars:
                bar.close()


def _manifest(dataset: Dataset, records, failures, seconds: float, scheduler, workers) -> dict:
    from ..survey import versions
    return {
        "versions": versions(),
        "dataset": dataset.resolved,
        "file": dataset.file,
        "base_scene": dataset.base.file,
        "scheduler": scheduler or f"LocalCluster({workers or os.cpu_count()} workers)",
        "seconds": round(seconds, 3),
        "plots": {"total": len(dataset.plots), "finished": len(records),
                  "skipped": sum(bool(r.get("skipped")) for r in records), "failed": failures},
        "points": sum(r["points"] for r in records),
        "tiles": sum(len(r.get("tiles", [])) for r in records),
        "seconds_per_plot": {r["plot"]: r.get("seconds") for r in sorted(records, key=lambda r: r["plot"])},
    }
