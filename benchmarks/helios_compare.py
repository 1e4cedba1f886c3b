"""HELIOS++ and mitsuforest side by side on one leg of a scene.

Exports the scene with its survey cut to one leg (``mitsuforest export``), flies that leg in HELIOS++
(``helios++ EXPORT/<name>_helios_survey.xml``) and here (``mitsuforest render`` of the same scene),
each in its own process, and prints wall time, peak memory (the process's maximum resident set),
points, returns per pulse, class shares and the offset between each tree's point centroids (a tree: one placed tree, wood and leaves; the
deadwood too).
HELIOS++'s ``hitObjectId`` is our object_id (see README, "HELIOS++"), which gives its points' trees.

Without ``helios++`` (the binary) or ``helios`` (the command pip installs, which runs the binary with
``--assets`` the working folder and ``--legacyEnergyModel``) on PATH, or ``--helios``, it says so and
exits 0. See README, "HELIOS++", for building HELIOS++ from source.

Each process's output (stdout and stderr) is kept in ``WORK/logs/``: ``helios.log`` holds HELIOS++'s
own log, whose errors (a kd-tree that does not fit, say) show there; a failing run prints its tail.
``--helios-args`` passes flags to HELIOS++ (``--kdtJobs 1`` for large scenes).

    python benchmarks/helios_compare.py                                  # demo scene, its middle leg
    python benchmarks/helios_compare.py --scene scenes/open.yaml --leg 5 --helios ~/helios/build/helios++ \
        --helios-args "--kdtJobs 1"
"""

from __future__ import annotations

import argparse
import csv
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
HELIOS_COLUMNS = ("x", "y", "z", "intensity", "echo_width", "return_number", "number_of_returns",
                  "fullwave_index", "object_id", "classification", "gps_time")   # HELIOS++ 2.x .xyz output


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path, default=ROOT / "scenes" / "demo.yaml")
    p.add_argument("--leg", type=int, help="leg number, 1-based (default: the middle one)")
    p.add_argument("--helios", help="the helios++ executable (default: helios++, else helios, on PATH)")
    p.add_argument("--work", type=Path, help="working folder (default: a temporary one)")
    p.add_argument("--quick", action="store_true", help="100 kHz and 7 sub-rays (a smoke test)")
    p.add_argument("--helios-args", default="", help="flags added to the helios++ command, one string "
                   "(e.g. \"--kdtJobs 1\")")
    args = p.parse_args(argv)
    helios = args.helios or shutil.which("helios++") or shutil.which("helios")
    if args.helios and not shutil.which(args.helios):
        print(f"--helios {args.helios}: no such executable", file=sys.stderr)
        return 2
    if not helios or not Path(helios).exists():
        print("helios++ not found (not on PATH and no --helios): nothing to compare. "
              "See README, 'HELIOS++', to build it from source.")
        return 0
    work = args.work or Path(tempfile.mkdtemp(prefix="helios_compare-"))
    work.mkdir(parents=True, exist_ok=True)
    scene_file = one_leg_scene(args.scene, args.leg, work, args.quick)
    export, logs = work / "export", work / "logs"
    logs.mkdir(exist_ok=True)
    run([sys.executable, "-m", "mitsuforest", "export", str(scene_file), "-o", str(export)], logs / "export.log")
    name = yaml.safe_load(scene_file.read_text())["name"]
    ours_dir, helios_dir = work / "ours", work / "helios_out"
    theirs = run([helios, str(export / f"{name}_helios_survey.xml"), "--output", str(helios_dir),
                  *shlex.split(args.helios_args)], logs / "helios.log", cwd=work)   # first: its errors come early
    ours = run([sys.executable, "-m", "mitsuforest", "render", str(scene_file), "-o", str(ours_dir),
                "--overwrite", "--quiet"], logs / "render.log")
    tree_of_part = {int(r["part_id"]): int(r["instance"]) if int(r["treeid"]) else 0
                    for r in read_csv(export / f"{name}_helios_parts.csv")}
    a = ours_points(ours_dir / f"{name}.pcd")
    b = helios_points(helios_dir, tree_of_part)
    report(args.scene, ours, theirs, a, b)
    print(f"logs: {logs}")
    return 0


def one_leg_scene(scene: Path, leg: int | None, work: Path, quick: bool = False) -> Path:
    """The scene file with its survey cut to one leg of its plan (same altitude, speed, frequencies)."""
    from mitsuforest.config import load_scene
    from mitsuforest.survey import make_plan
    plan = make_plan(load_scene(scene))
    k = (leg or (len(plan.legs) + 1) // 2) - 1
    chosen = plan.legs[k]
    data = yaml.safe_load(scene.read_text())
    data.setdefault("survey", {})["lines"] = [[list(chosen.start[:2]), list(chosen.end[:2])]]
    data["name"] = f"{data.get('name') or scene.stem}_leg{k + 1}"
    if isinstance(data.get("sensor"), str):
        data["sensor"] = str((scene.parent / data["sensor"]).resolve())
    data.pop("output", None)
    if quick:
        data["survey"]["pulse_frequency"] = 100000
        data.setdefault("simulation", {})["beam_samples"] = 7
    path = work / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run(command, log: Path, cwd=None) -> dict:
    """Run a command in its own process, its stdout and stderr kept in ``log``: wall seconds and its peak
    resident memory (GB). A failing command ends this script with the tail of its log."""
    start = time.perf_counter()
    with open(log, "wb") as out:
        proc = subprocess.Popen(command, cwd=cwd, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        tail = log.read_bytes()[-3000:].decode(errors="replace")
        sys.exit(f"{' '.join(map(str, command))} failed ({code}); its log, {log}, ends:\n{tail}")
    return {"seconds": seconds, "peak_gb": usage.ru_maxrss * 1024 / 1e9, "log": log}


def read_csv(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def ours_points(path: Path) -> dict:
    from mitsuforest.write import read_pcd
    pts = read_pcd(path)
    out = {k: np.asarray(pts[k]) for k in ("x", "y", "z", "return_number", "number_of_returns", "classification")}
    out["tree"] = np.where(np.asarray(pts["treeid"]) > 0, np.asarray(pts["instance"]), 0).astype(np.int64)
    return out


def helios_points(folder: Path, tree_of_part: dict) -> dict:
    files = sorted(folder.rglob("leg*_points.xyz"))
    if not files:
        sys.exit(f"no leg*_points.xyz under {folder}: did HELIOS++ write LAS (--lasOutput)? Run it without.")
    rows = np.vstack([np.loadtxt(f, ndmin=2, usecols=range(len(HELIOS_COLUMNS))) for f in files])
    out = {k: rows[:, i] for i, k in enumerate(HELIOS_COLUMNS)}
    for k in ("return_number", "number_of_returns", "classification", "object_id"):
        out[k] = out[k].astype(np.int64)
    out["tree"] = np.array([tree_of_part.get(int(i), 0) for i in out["object_id"]], np.int64)
    return out


def report(scene: Path, ours: dict, theirs: dict, a: dict, b: dict) -> None:
    from mitsuforest.classes import CLASS_NAMES
    print(f"{scene.name}, one leg                mitsuforest      HELIOS++")
    print(f"wall time (s)                   {ours['seconds']:12.1f}  {theirs['seconds']:12.1f}")
    print(f"peak memory (GB)                {ours['peak_gb']:12.2f}  {theirs['peak_gb']:12.2f}")
    print(f"points                          {len(a['x']):12,d}  {len(b['x']):12,d}")
    for n in range(1, 8):
        pa, pb = (np.sum((p["number_of_returns"] == n) & (p["return_number"] == 1)) for p in (a, b))
        if pa or pb:
            print(f"pulses with {n} return(s)          {pa:12,d}  {pb:12,d}")
    for code, cname in CLASS_NAMES.items():
        sa, sb = (np.mean(p["classification"] == code) if len(p["x"]) else 0.0 for p in (a, b))
        print(f"share {cname:<26}{sa:12.1%}  {sb:12.1%}")
    print("tree (instance)  centroid offset (m)  points here  points HELIOS++")
    for tree in sorted(set(a["tree"][a["tree"] > 0]) | set(b["tree"][b["tree"] > 0])):
        ia, ib = a["tree"] == tree, b["tree"] == tree
        if ia.sum() and ib.sum():
            ca, cb = (np.array([p[c][i].mean() for c in "xyz"]) for p, i in ((a, ia), (b, ib)))
            offset = f"{np.linalg.norm(ca - cb):.3f}"
        else:
            offset = "-"
        print(f"{tree:15d}  {offset:>19}  {ia.sum():11,d}  {ib.sum():15,d}")


if __name__ == "__main__":
    raise SystemExit(main())
