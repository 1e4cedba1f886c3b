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
    python benchmarks/fixed_costs.py --against ../base # and another checkout's package, plot by plot in turn
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import os
import pstats
import shutil
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

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
    ("mitsuforest.scan.tracer", "PulseTracer", "tracer setup"),     # the proxies' cells and scene, the kernel's tables
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

    def install(self, package: str = "mitsuforest"):
        for module, name, stage in STAGES:
            owner = _owner(package + module.removeprefix("mitsuforest"))
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


class Checkout:
    """A package whose plots are rendered and timed: its dataset worker's task and its stage clock."""

    def __init__(self, package: str, label: str):
        self.label = label
        start = time.process_time()
        self.tasks = importlib.import_module(package + ".dataset.tasks")
        self.imports = time.process_time() - start
        self.clock = StageClock()
        self.clock.install(package)
        self.rows = []

    def render(self, root: Path, name: str) -> None:
        start = time.process_time()
        record = self.tasks.render_plot(str(root), name, threads=1)
        total = time.process_time() - start
        stages = self.clock.take()
        stages["other"] = total - sum(stages.values())
        self.rows.append((name, record["points"], total, stages))


def against_package(checkout: Path, folder: Path) -> str:
    """``checkout``'s package importable beside this one, as ``mitsuforest_against`` (a copy in ``folder``):
    both render in one process, plot by plot in turn, so that a shared machine's changing speed is the
    same for both. Its modules must import each other relatively (checked)."""
    source = Path(checkout) / "mitsuforest"
    for path in source.rglob("*.py"):
        for line in path.read_text().splitlines():
            if line.startswith(("import mitsuforest", "from mitsuforest")):
                raise SystemExit(f"--against: {path} imports the package by name ({line.strip()}); cannot copy it")
    shutil.copytree(source, folder / "mitsuforest_against", ignore=shutil.ignore_patterns("__pycache__"))
    sys.path.insert(0, str(folder))
    return "mitsuforest_against"


def make_plots(folder: Path, plots: int, pictures: bool, quick: bool = False) -> list[str]:
    """The scene files of ``benchmarks/dataset.py``'s demo-size plots in ``folder``; their names."""
    from mitsuforest.dataset import files
    from mitsuforest.dataset.spec import load_dataset
    from dataset import demo_dataset
    dataset = load_dataset(demo_dataset(folder, plots, pictures, quick))
    for plot in dataset.plots:
        scene = plot.scene.with_({"output.dir": str(files.plot_folder(folder, plot.name))})
        files.write_scene_file(files.scene_file(folder, plot.name), scene)
    return [p.name for p in dataset.plots]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plots", type=int, default=8)
    p.add_argument("--no-pictures", action="store_true")
    p.add_argument("--against", type=Path, metavar="CHECKOUT",
                   help="also render each plot with another checkout's package, in turn in this process")
    p.add_argument("--profile", type=int, default=0, metavar="N", help="cProfile plots 2..: the N costliest functions")
    p.add_argument("--sort", default="tottime", help="cProfile sort key (tottime, cumulative)")
    p.add_argument("--dump", type=Path, help="also write the profile here (pstats)")
    p.add_argument("--quick", action="store_true", help="2 small plots: one line, a thin beam (CI)")
    args = p.parse_args()
    if args.quick:
        args.plots = 2
    os.environ.setdefault("MITSUFOREST_CACHE", str(Path.home() / ".cache" / "mitsuforest"))
    profiler = cProfile.Profile() if args.profile else None
    with tempfile.TemporaryDirectory() as tmp:
        checkouts = [Checkout("mitsuforest", "this checkout")]
        if args.against:
            checkouts.append(Checkout(against_package(args.against, Path(tmp)), str(args.against)))
        roots = [Path(tmp, f"plots{k}") for k in range(len(checkouts))]
        for root in roots:
            root.mkdir()
            names = make_plots(root, args.plots, not args.no_pictures, args.quick)
        for i, name in enumerate(names):
            if profiler and i == 1:
                profiler.enable()
            turn = list(zip(checkouts, roots))
            for checkout, root in turn if i % 2 == 0 else turn[::-1]:
                checkout.render(root, name)
        if profiler:
            profiler.disable()
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    order = list(dict.fromkeys([s for _, _, s in STAGES] + ["other"]))
    means = [print_table(c, order) for c in checkouts]
    if len(checkouts) == 2:
        print(f"\n| stage, mean of plots 2.. | {checkouts[0].label} | {checkouts[1].label} |\n| --- | --- | --- |")
        for stage in ["CPU s", "fixed costs", *order]:
            print(f"| {stage} | {means[0][stage]:.3f} | {means[1][stage]:.3f} |")
    if profiler:
        pstats.Stats(profiler).sort_stats(args.sort).print_stats(args.profile)
        if args.dump:
            profiler.dump_stats(args.dump)


def print_table(checkout: Checkout, order: list[str]) -> dict:
    """Print a checkout's table, plot by plot; its means over plots 2.. (the first pays for imports and
    compiling), with ``CPU s`` and ``fixed costs`` (all but the scan)."""
    print(f"\n{checkout.label}: imports {checkout.imports:.2f} CPU s\n")
    print("| plot | points | CPU s | " + " | ".join(order) + " |")
    print("| --- " * (len(order) + 3) + "|")
    for name, points, total, stages in checkout.rows:
        print(f"| {name} | {points:,} | {total:.2f} | " + " | ".join(f"{stages.get(s, 0):.3f}" for s in order) + " |")
    later = checkout.rows[1:] or checkout.rows
    mean = {s: sum(r[3].get(s, 0) for r in later) / len(later) for s in order}
    mean["CPU s"] = sum(r[2] for r in later) / len(later)
    mean["fixed costs"] = mean["CPU s"] - mean["scan + points"]
    print(f"| mean of plots 2.. | | {mean['CPU s']:.2f} | " + " | ".join(f"{mean[s]:.3f}" for s in order) + " |")
    print(f"\nper plot after the first: {mean['CPU s']:.2f} CPU s, of which scan + points {mean['scan + points']:.2f} s, "
          f"fixed costs {mean['fixed costs']:.2f} s")
    return mean


if __name__ == "__main__":
    main()
