"""A tree list's plot planned and its models built from an empty cache, in one process and with the
trees stage's worker processes (``MITSUFOREST_BUILD_PROCESSES``, issue 30): every listed tree is grown
anew, as a twin's calibration grows each of its renders' trees. Each run is a fresh ``mitsuforest``
process with a cache of its own; the plan's and the models' seconds come from the manifest, the CPU
seconds of the process and its workers from ``os.wait4``. The plans must be the same bytes.

    python benchmarks/tree_list.py                     # 120 trees on 0.5 ha, 0 then the default workers
    python benchmarks/tree_list.py --trees 400 --size 100 --processes 0 2 --repeat 2
    python benchmarks/tree_list.py --quick             # 12 trees, plan only (CI)
    python benchmarks/tree_list.py --against ../base   # and another checkout's package (its default), in turn
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def write_scene(folder: Path, trees: int, size: float) -> Path:
    """A flat plot of ``size`` m a side holding ``trees`` listed trees 8-30 m tall (seeded), a thin
    beam over it: the trees dominate the render's cost."""
    rng = np.random.default_rng(1)
    rows = zip(rng.uniform(1, size - 1, trees), rng.uniform(1, size - 1, trees), rng.uniform(8, 30, trees),
               rng.uniform(1, 4, trees))
    (folder / "trees.csv").write_text("x,y,height,crown_radius\n" +
                                      "".join(f"{x:.2f},{y:.2f},{h:.1f},{r:.2f}\n" for x, y, h, r in rows))
    scene = folder / "list.yaml"
    scene.write_text(f"""name: list
seed: 3
area: {{size: [{size:g}, {size:g}]}}
terrain: {{type: flat}}
forest: {{trees_file: trees.csv}}
sensor: {ROOT / 'sensors' / 'riegl_vux-1uav22.yaml'}
survey: {{altitude: 60, speed: 8, pulse_frequency: 100000, scan_frequency: 50, line_spacing: 40}}
simulation: {{beam_samples: 1, beam_pattern: fixed}}
output: {{formats: [laz]}}
""")
    return scene


def run(package: Path, scene: Path, out: Path, command: str, processes: str | None) -> dict:
    """One fresh ``mitsuforest COMMAND`` of ``package`` (a checkout) into ``out``, with a cache of its own."""
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "MITSUFOREST_CACHE": str(out / "cache"), "PYTHONPATH": str(package)}
    env.pop("MITSUFOREST_BUILD_PROCESSES", None)
    if processes is not None:
        env["MITSUFOREST_BUILD_PROCESSES"] = processes
    args = [sys.executable, "-m", "mitsuforest", command, str(scene), "-o", str(out / "files")]
    start = time.perf_counter()
    child = subprocess.Popen(args + (["--quiet"] if command == "render" else []), env=env, cwd=package,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"{command} failed: {child.stderr.read()}")
    plan = out / "files" / "list_plan.json"
    manifest = out / "files" / "list_manifest.json"
    stages = json.loads(manifest.read_text())["timings_s"] if manifest.exists() else {}
    return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "stages": stages,
            "plan_sha": hashlib.sha256(plan.read_bytes()).hexdigest()[:12]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trees", type=int, default=120)
    p.add_argument("--size", type=float, default=70.0, help="the plot's side (m)")
    p.add_argument("--processes", nargs="+", default=["0", "default"],
                   help="MITSUFOREST_BUILD_PROCESSES of each run ('default': unset)")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--plan-only", action="store_true", help="mitsuforest plan instead of render")
    p.add_argument("--against", type=Path, help="another checkout, run at its default beside each repeat")
    p.add_argument("--quick", action="store_true", help="12 trees on 30 m, plan only")
    args = p.parse_args()
    if args.quick:
        args.trees, args.size, args.plan_only = 12, 30.0, True
    command = "plan" if args.plan_only else "render"
    with tempfile.TemporaryDirectory(prefix="tree-list-") as tmp:
        scene = write_scene(Path(tmp), args.trees, args.size)
        print(f"{args.trees} listed trees on {args.size:g} m, mitsuforest {command}, fresh caches, "
              f"{os.cpu_count()} cores")
        digests = set()
        for r in range(args.repeat):
            runs = [(f"processes {p}", ROOT, None if p == "default" else p) for p in args.processes]
            if args.against:
                runs.append((f"{args.against.name} (default)", args.against.resolve(), None))
            for label, package, processes in runs:
                got = run(package, scene, Path(tmp) / "out", command, processes)
                digests.add(got["plan_sha"])
                stages = ", ".join(f"{k} {got['stages'][k]:.1f}" for k in ("plan", "trees") if k in got["stages"])
                print(f"  {r + 1}  {label:<22} wall {got['wall']:6.1f} s  CPU {got['cpu']:6.1f} s"
                      f"{'  ' + stages if stages else ''}  plan {got['plan_sha']}")
        print("plans: the same bytes" if len(digests) == 1 else f"plans DIFFER: {sorted(digests)}")
        if len(digests) != 1:
            sys.exit(1)


if __name__ == "__main__":
    main()
