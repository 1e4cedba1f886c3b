"""Where a dataset worker's CPU goes, plot after plot: the fixed costs of small plots (issue 30).

Renders demo-size plots one after the other in this one process, as a dataset worker does
(:func:`mitsuforest.dataset.tasks.render_plot`, 1 Dr.Jit thread), the plots those of
``benchmarks/dataset.py`` (the demo with 3–7 trees, the VUX-1UAV22 at 200 kHz, 19 sub-rays). Each
stage's CPU seconds (``time.process_time``: every thread of the process, the writer's included) are
taken around the functions named below, each without the stages it calls; "other" is the rest of the
task. The first plot pays for imports and kernel compilation and is shown apart.

    python benchmarks/fixed_costs.py                   # 8 plots
    python benchmarks/fixed_costs.py --plots 4 --no-pictures
    python benchmarks/fixed_costs.py --profile 20      # also cProfile plots 2.., the 20 costliest functions
    python benchmarks/fixed_costs.py --quick           # 2 small plots, one line, a thin beam (CI)
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import os
import pstats
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# (module, attribute, stage): the functions timed, where their callers look them up.
STAGES = [
    ("mitsuforest.pipeline", "_as_scene", "load scene"),
    ("mitsuforest.pipeline", "check_output", "check output"),
    ("mitsuforest.survey", "make_plan", "plan"),
    ("mitsuforest.survey", "build_models", "models"),
    ("mitsuforest.survey", "build_scene", "mitsuba scene"),
    ("mitsuforest.survey", "PointWriter", "point writer setup"),
    ("mitsuforest.survey", "_drain", "scan + points"),
    ("mitsuforest.write.PointWriter", "close", "points close"),
    ("mitsuforest.write.PointWriter", "statistics", "statistics"),
    ("mitsuforest.survey", "_manifest", "statistics"),
    ("mitsuforest.survey", "import_report", "statistics"),
    ("mitsuforest.survey", "realism_table", "statistics"),
    ("mitsuforest.write", "write_volumes", "tables"),
    ("mitsuforest.write", "write_ids", "tables"),
    ("mitsuforest.write", "write_trajectory", "tables"),
    ("mitsuforest.write", "write_text", "tables"),
    ("mitsuforest.write", "write_top_figure", "picture: top"),
    ("mitsuforest.write", "write_tile_figure", "picture: side"),
    ("mitsuforest.write", "write_profile_figure", "picture: profile"),
    ("mitsuforest.write", "write_returns_figure", "picture: returns"),
    ("mitsuforest.write", "write_manifest", "tables"),
    ("mitsuforest.write.Staging", "commit", "commit"),
    ("mitsuforest.dataset.tasks", "_finish", "record"),
]


class StageClock:
    """CPU seconds by stage, each call's own (the stages it calls are theirs)."""

    def __init__(self):
        self.seconds = defaultdict(float)
        self._children = []

    def wrap(self, fn, stage):
        def timed(*args, **kwargs):
            self._children.append(0.0)
            start = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.process_time() - start
                nested = self._children.pop()
                self.seconds[stage] += spent - nested
                if self._children:
                    self._children[-1] += spent
        timed.__wrapped__ = fn
        return timed

    def install(self):
        for module, name, stage in STAGES:
            owner = _owner(module)
            setattr(owner, name, self.wrap(getattr(owner, name), stage))

    def take(self) -> dict:
        out, self.seconds = dict(self.seconds), defaultdict(float)
        return out


def _owner(dotted: str):
    try:
        return importlib.import_module(dotted)
    except ModuleNotFoundError:
        module, _, cls = dotted.rpartition(".")
        return getattr(importlib.import_module(module), cls)


def make_plots(folder: Path, plots: int, pictures: bool, quick: bool = False) -> list[str]:
    """The scene files of ``benchmarks/dataset.py``'s demo-size plots in ``folder``; their names."""
    from mitsuforest.dataset import files
    from mitsuforest.dataset.spec import load_dataset
    base = yaml.safe_load((ROOT / "scenes" / "demo.yaml").read_text())
    base["sensor"] = str(ROOT / "sensors" / "riegl_vux-1uav22.yaml")
    base["output"] = {"pictures": pictures}
    if quick:
        base["survey"].update({"lines": [[[10, -2], [10, 22]]], "pulse_frequency": 100000})
        base["simulation"] = {"beam_samples": 1, "beam_pattern": "fixed"}
    (folder / "demo_base.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    (folder / "demo_plots.yaml").write_text(yaml.safe_dump(
        {"name": "demo_plots", "base": "demo_base.yaml", "plots": plots, "vary": {"forest.trees": {"range": [3, 7]}}}))
    dataset = load_dataset(folder / "demo_plots.yaml")
    for plot in dataset.plots:
        scene = plot.scene.with_({"output.dir": str(files.plot_folder(folder, plot.name))})
        files.write_scene_file(files.scene_file(folder, plot.name), scene)
    return [p.name for p in dataset.plots]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plots", type=int, default=8)
    p.add_argument("--no-pictures", action="store_true")
    p.add_argument("--profile", type=int, default=0, metavar="N", help="cProfile plots 2..: the N costliest functions")
    p.add_argument("--sort", default="tottime", help="cProfile sort key (tottime, cumulative)")
    p.add_argument("--dump", type=Path, help="also write the profile here (pstats)")
    p.add_argument("--quick", action="store_true", help="2 small plots: one line, a thin beam (CI)")
    args = p.parse_args()
    if args.quick:
        args.plots = 2
    os.environ.setdefault("MITSUFOREST_CACHE", str(Path.home() / ".cache" / "mitsuforest"))
    start = time.process_time()
    from mitsuforest.dataset import tasks
    imports = time.process_time() - start
    clock = StageClock()
    clock.install()
    profiler = cProfile.Profile() if args.profile else None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        names = make_plots(Path(tmp), args.plots, not args.no_pictures, args.quick)
        for i, name in enumerate(names):
            if profiler and i == 1:
                profiler.enable()
            start = time.process_time()
            record = tasks.render_plot(tmp, name, threads=1)
            total = time.process_time() - start
            stages = clock.take()
            stages["other"] = total - sum(stages.values())
            rows.append((name, record["points"], total, stages))
        if profiler:
            profiler.disable()
    print(f"imports {imports:.2f} CPU s; {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}\n")
    order = list(dict.fromkeys([s for _, _, s in STAGES] + ["other"]))
    print("| plot | points | CPU s | " + " | ".join(order) + " |")
    print("| --- " * (len(order) + 3) + "|")
    for name, points, total, stages in rows:
        print(f"| {name} | {points:,} | {total:.2f} | " + " | ".join(f"{stages.get(s, 0):.3f}" for s in order) + " |")
    later = rows[1:] or rows
    mean = {s: sum(r[3].get(s, 0) for r in later) / len(later) for s in order}
    total = sum(r[2] for r in later) / len(later)
    fixed = total - mean["scan + points"]
    print(f"| mean of plots 2.. | | {total:.2f} | " + " | ".join(f"{mean[s]:.3f}" for s in order) + " |")
    print(f"\nper plot after the first: {total:.2f} CPU s, of which scan + points {mean['scan + points']:.2f} s, "
          f"fixed costs {fixed:.2f} s")
    if profiler:
        pstats.Stats(profiler).sort_stats(args.sort).print_stats(args.profile)
        if args.dump:
            profiler.dump_stats(args.dump)


if __name__ == "__main__":
    main()
