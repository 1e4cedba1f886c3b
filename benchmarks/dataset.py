"""`mitsuforest dataset` at scale: many demo-size plots on 1 and 2 workers, and one large plot split by
flight leg.

    python benchmarks/dataset.py                  # 8 demo plots on 1 and 2 workers; a 4 ha plot, one leg a task
    python benchmarks/dataset.py --skip-plots --large-pulse-frequency 200000 --large-speed 2   # the paper's survey
    python benchmarks/dataset.py --large-beam 19  # the 4 ha plot at the default beam (long)
    python benchmarks/dataset.py --quick          # 2 small plots and a small split plot with tiles, 2 workers (CI)
    python benchmarks/dataset.py --plots 32 --workers 2 --skip-large --no-pictures   # fixed costs, no pictures
    python benchmarks/dataset.py --skip-plots --workers 2 --large-size 300 --large-tiles 20 --tiles-only
                                                  # issue 30: 9 ha split by legs, tiles written by the leg tasks

With ``--large-tiles`` the split plot is cut into tiles by its leg tasks and tile tasks (with
``--tiles-only``, ``tiles.plot_files: false``: no merge); the longest leg task, tile task, merge and the
record's task are printed, so that a single-process stage longer than a leg shows.

Each run gets a fresh LocalCluster (one process a worker, Dr.Jit threads = cores / workers) and
reads its figures from the dataset's records and manifest; the workers' peak memory is their own
``ru_maxrss``. Every plot is a full render (all files), as ``mitsuforest dataset`` writes it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run(dataset_file: Path, out: Path, workers: int) -> dict:
    """One dataset run on a fresh LocalCluster; wall time, the manifest and the workers' peak memory."""
    from dask.distributed import Client, LocalCluster
    from mitsuforest.dataset import run_dataset
    cores = os.cpu_count() or 1
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        start = time.perf_counter()
        manifest = run_dataset(dataset_file, out, scheduler=cluster.scheduler_address,
                               threads=max(1, cores // workers), progress=False, log=lambda *_: None)
        wall = time.perf_counter() - start
        peaks = client.run(_peak_rss_mb)
        cpu = client.run(_cpu_seconds)
    return {"wall": wall, "manifest": manifest, "worker_peak_mb": sorted(peaks.values()),
            "worker_cpu_s": sum(cpu.values()), "load": os.getloadavg()[0]}


def write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def demo_dataset(folder: Path, plots: int, pictures: bool = True, quick: bool = False) -> Path:
    """``folder/demo_plots.yaml``: ``plots`` demo-size plots of 3-7 trees on ``folder/demo_base.yaml`` (the
    demo scene with the VUX-1UAV22; ``quick``: one line, a thin beam); returns the dataset file."""
    base = yaml.safe_load((ROOT / "scenes" / "demo.yaml").read_text())
    base["sensor"] = str(ROOT / "sensors" / "riegl_vux-1uav22.yaml")
    base["output"] = {"pictures": pictures}
    if quick:
        base["survey"].update({"lines": [[[10, -2], [10, 22]]], "pulse_frequency": 100000})
        base["simulation"] = {"beam_samples": 1, "beam_pattern": "fixed"}
    write_yaml(folder / "demo_base.yaml", base)
    return write_yaml(folder / "demo_plots.yaml", {"name": "demo_plots", "base": "demo_base.yaml",
                                                   "plots": plots, "vary": {"forest.trees": {"range": [3, 7]}}})


def many_plots(folder: Path, plots: int, worker_counts, quick: bool, pictures: bool = True) -> list[dict]:
    dataset = demo_dataset(folder, plots, pictures, quick)
    rows = []
    for workers in worker_counts:
        r = run(dataset, folder / f"plots_{workers}w", workers)
        per_plot = list(r["manifest"]["seconds_per_plot"].values())
        rows.append({"workers": workers, "wall_s": round(r["wall"], 1), "plots": len(per_plot),
                     "mean_plot_s": round(sum(per_plot) / len(per_plot), 2),
                     "points": r["manifest"]["points"], "worker_peak_mb": [round(m) for m in r["worker_peak_mb"]],
                     "cpu_per_plot_s": round(r["worker_cpu_s"] / len(per_plot), 1), "load": round(r["load"], 1)})
    one = rows[0]["wall_s"]
    for row in rows:
        row["speed_up"] = round(one / row["wall_s"], 2)
    return rows


def large_plot(folder: Path, size: float, beam: int, workers: int, legs_per_task: int, pulse_frequency: float,
               speed: float, tiles: dict | None = None) -> dict:
    base = yaml.safe_load((ROOT / "scenes" / "open.yaml").read_text())
    base["sensor"] = str(ROOT / "sensors" / "riegl_vux-1uav22.yaml")
    base.pop("output", None)
    scale = size * size / 1e4
    base["area"] = {"size": [size, size]}
    if base["forest"].get("trees"):
        base["forest"]["trees"] = max(1, round(base["forest"]["trees"] * scale))
    base["understory"] = {k: max(1, round(v * scale)) for k, v in base.get("understory", {}).items()} or None
    if base["understory"] is None:
        base.pop("understory")
    base["simulation"] = {"beam_samples": beam, "beam_pattern": "fixed" if beam == 1 else "stratified"}
    base["survey"]["pulse_frequency"] = pulse_frequency
    base["survey"]["speed"] = speed
    write_yaml(folder / "large_base.yaml", base)
    spec = {"name": "large", "base": "large_base.yaml", "plots": 1, "legs_per_task": legs_per_task}
    if tiles:
        spec["tiles"] = tiles
    dataset = write_yaml(folder / "large.yaml", spec)
    r = run(dataset, folder / "large", workers)
    record = json.loads((folder / "large" / "plots" / "plot_0000" / "plot_0000_dataset.json").read_text())
    legs = record["leg_tasks"]
    leg_seconds = sorted(x["task_seconds"] for x in legs)
    tile_seconds = sorted(x["task_seconds"] for x in record.get("tile_tasks", []))
    merge = record.get("merge_seconds")
    return {"area_ha": round(scale, 2), "beam_samples": beam, "survey": f"{pulse_frequency:g} Hz at {speed:g} m/s", "workers": workers, "wall_s": round(r["wall"], 1),
            "leg_tasks": len(legs), "pulses": record["pulses"], "points": record["points"],
            "mean_leg_task_s": round(sum(leg_seconds) / len(legs), 2),
            "mean_leg_scan_s": round(sum(x["scan_seconds"] for x in legs) / len(legs), 2),
            "longest_leg_task_s": leg_seconds[-1], "median_leg_task_s": leg_seconds[len(legs) // 2],
            "tiles": len(record["tiles"]), "tile_tasks": len(tile_seconds),
            "tile_points": sum(t["points"] for t in record["tiles"]),
            "longest_tile_task_s": tile_seconds[-1] if tile_seconds else None,
            "median_tile_task_s": tile_seconds[len(tile_seconds) // 2] if tile_seconds else None,
            "finish_s": record.get("finish_seconds"),
            "merge_s": merge, "merge_points_per_s": round(record["points"] / merge) if merge else None,
            "worker_peak_mb": [round(m) for m in r["worker_peak_mb"]], "worker_cpu_s": round(r["worker_cpu_s"]),
            "load": round(r["load"], 1)}


def print_large(r: dict) -> None:
    merge = (f"merge {r['merge_s']} s ({r['merge_points_per_s']:,} points/s)" if r["merge_s"] is not None
             else "no merge (tiles only)")
    print(f"\nlarge plot: {r['area_ha']} ha, {r['beam_samples']} sub-rays, {r['survey']}, {r['workers']} workers, "
          f"{r['leg_tasks']} leg tasks: wall {r['wall_s']} s; {r['pulses']:,} pulses, {r['points']:,} points; "
          f"per leg task {r['mean_leg_task_s']} s (scan {r['mean_leg_scan_s']} s); {merge}; worker CPU "
          f"{r['worker_cpu_s']} s; peak memory per worker " + ", ".join(f"{m} MB" for m in r["worker_peak_mb"])
          + f"; load average {r['load']}", flush=True)
    if r["tile_tasks"]:
        stages = {"merge": r["merge_s"] or 0, "tile task": r["longest_tile_task_s"], "record": r["finish_s"]}
        longest = max(stages, key=stages.get)
        print(f"tiles: {r['tiles']} tiles ({r['tile_points']:,} points with their buffers) in {r['tile_tasks']} tile "
              f"tasks; longest leg task {r['longest_leg_task_s']} s (median {r['median_leg_task_s']} s), longest tile "
              f"task {r['longest_tile_task_s']} s (median {r['median_tile_task_s']} s), {merge}, record "
              f"{r['finish_s']} s; longest single-process stage after the legs: the {longest}, {stages[longest]} s, "
              + ("no longer than" if stages[longest] <= r["longest_leg_task_s"] else "LONGER than")
              + " the longest leg task", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plots", type=int, default=8)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--large-size", type=float, default=200.0, help="side of the large plot, m (200: 4 ha)")
    p.add_argument("--large-beam", type=int, default=1, help="sub-rays of the large plot (1: thin beam)")
    p.add_argument("--large-pulse-frequency", type=float, default=100000.0,
                   help="pulse rate of the large plot's survey, Hz (the paper's 200000 at 2 m/s is 10x the pulses)")
    p.add_argument("--large-speed", type=float, default=10.0, help="flying speed of the large plot's survey, m/s")
    p.add_argument("--legs-per-task", type=int, default=1)
    p.add_argument("--large-tiles", type=float, help="cut the large plot into tiles of this size, m (issue 30)")
    p.add_argument("--large-tile-buffer", type=float, default=2.0, help="the tiles' buffer, m")
    p.add_argument("--tiles-only", action="store_true", help="the large plot's tiles only (tiles.plot_files: false)")
    p.add_argument("--skip-large", action="store_true")
    p.add_argument("--no-pictures", action="store_true", help="the plots with output.pictures: false")
    p.add_argument("--skip-plots", action="store_true", help="only the large plot")
    p.add_argument("--quick", action="store_true", help="2 small plots and a 30 m split plot on 2 workers (CI)")
    p.add_argument("--out", type=Path, help="keep the datasets here (default: a temporary folder)")
    args = p.parse_args()
    if args.quick:
        args.plots, args.large_size, args.workers = 2, 30.0, [2]
        args.large_tiles = args.large_tiles or 10.0
    os.environ.setdefault("MITSUFOREST_CACHE", str(Path.home() / ".cache" / "mitsuforest"))
    print(f"machine: {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if not args.skip_plots:
            plots_table(folder, args)
        if not args.skip_large:
            tiles = args.large_tiles and {"size": args.large_tiles, "buffer": args.large_tile_buffer, "format": "laz",
                                          "plot_files": not args.tiles_only}
            print_large(large_plot(folder, args.large_size, args.large_beam, max(args.workers), args.legs_per_task,
                                   args.large_pulse_frequency, args.large_speed, tiles or None))
        print(f"client peak memory {_peak_rss_mb():.0f} MB")


def plots_table(folder: Path, args) -> None:
    print(f"{args.plots} demo-size plots\n")
    print("| workers | wall | plots | mean time per plot (task) | worker CPU per plot | points | speed-up | "
          "peak memory per worker | load average at the end |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for row in many_plots(folder, args.plots, args.workers, args.quick, not args.no_pictures):
        print(f"| {row['workers']} | {row['wall_s']} s | {row['plots']} | {row['mean_plot_s']} s | "
              f"{row['cpu_per_plot_s']} s | {row['points']:,} | {row['speed_up']}x | "
              f"{', '.join(f'{m} MB' for m in row['worker_peak_mb'])} | {row['load']} |", flush=True)


if __name__ == "__main__":
    main()
