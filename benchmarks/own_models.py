"""Load-and-repair time and peak memory of a large imported tree mesh, and memory against placed copies.

    python benchmarks/own_models.py [--triangles 2000000] [--copies 1 40] [--quick] [--out DIR]

Writes a Y-up OBJ in centimetres (like a modelling tool's export) of about ``--triangles`` triangles,
half wood, half leaves: a procedural tree whose branches are finely meshed closed tubes, one object
each, with every 10th branch's end cap missing and every 25th inside out. Then, each in a fresh
process so that peak memory (ru_maxrss) is the step's own:

1. ``build``: read, split wood from leaves, split the wood into loose parts, repair, union; cold cache.
2. ``cached``: the same model from the cache (keyed on the file's SHA-256).
3. ``scene``: the Mitsuba scene (llvm) of a plot with that model placed ``--copies`` times: one copy
   of the mesh in memory however many times it is placed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OPEN_EVERY, INSIDE_OUT_EVERY = 10, 25   # every 10th branch open (k % 10 == 9), every 25th inside out (k % 25 == 0)


def write_big_tree(path: Path, triangles: int) -> dict:
    """A tree mesh of about ``triangles`` triangles (half wood, half leaves); returns what it holds."""
    from mitsuforest.specs.archetypes import DEFAULT_ARCHETYPES
    from mitsuforest.trees.leaves import leaves_on_twigs
    from mitsuforest.trees.skeleton import grow, terminal_branches
    from mitsuforest.trees.tubes import tube
    a = DEFAULT_ARCHETYPES[4]
    branches = grow(a)
    refine = min(range(1, 50), key=lambda k: abs(_wood_triangles(branches, k) - triangles / 2))
    wood = []
    for b in branches:
        s = np.linspace(0, 1, (len(b.points) - 1) * refine + 1)
        t = np.linspace(0, 1, len(b.points))
        pts = np.column_stack([np.interp(s, t, b.points[:, k]) for k in range(3)])
        wood.append(tube(pts, np.interp(s, t, b.radii), _sides(b, refine)))
    wood_triangles = sum(len(f) for _, f in wood)
    leaf_area = max(triangles - wood_triangles, 2) / 2 * 0.5 * a.leaf_length * a.leaf_width
    twigs = [b.points for b in terminal_branches(branches)]
    leaf_v, leaf_f = leaves_on_twigs(twigs, leaf_area, a.leaf_length, a.leaf_width, a.leaf_inclination,
                                     a.leaf_clumping, np.random.default_rng(0))
    with open(path, "w") as out:
        out.write(f"mtllib {path.stem}.mtl\n")
        base = 1
        for k, (v, f) in enumerate(wood):
            if k % OPEN_EVERY == OPEN_EVERY - 1:
                cap = int(np.sum(f == len(v) - 1))
                v, f = v[:-1], f[:-cap]
            if k % INSIDE_OUT_EVERY == 0 and k:
                f = f[:, ::-1]
            base = _write_piece(out, f"Branch_{k:04d}", "bark", v, f, base)
        _write_piece(out, "Leaves", "leaf", leaf_v, leaf_f, base)
    path.with_suffix(".mtl").write_text("newmtl bark\nKd 0.4 0.3 0.2\nnewmtl leaf\nKd 0.2 0.5 0.2\n")
    return {"wood_parts": len(wood), "wood_triangles": int(sum(len(f) for _, f in wood)),
            "leaf_triangles": int(len(leaf_f)), "file_mb": round(path.stat().st_size / 1e6, 1)}


def _sides(branch, refine: int) -> int:
    """Rings and sides grow together with ``refine``; thinner orders get fewer sides."""
    return max(6, 24 * refine // (1 + branch.order))


def _wood_triangles(branches, refine: int) -> int:
    return sum(2 * (len(b.points) - 1) * refine * _sides(b, refine) + 2 * _sides(b, refine) for b in branches)


def _write_piece(out, name, material, v, f, base) -> int:
    cm = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]) * 100.0
    out.write(f"o {name}\nusemtl {material}\n")
    np.savetxt(out, cm, fmt="v %.4f %.4f %.4f")
    np.savetxt(out, f + base, fmt="f %d %d %d")
    return base + len(v)


def _entry(path):
    from mitsuforest.specs.sources import MeshTree
    return MeshTree(mesh=str(path), units="cm", up="y", leaves=("leaf*",))


def stage(name: str, path: Path, copies: int) -> dict:
    """One measured step, run in this (fresh) process."""
    from mitsuforest.trees.imported import imported_model
    t0 = time.perf_counter()
    if name in ("build", "cached"):
        model = imported_model(_entry(path), "big")
        v = model.volume
        result = {"union_m3": v.union, "naive_m3": v.naive, "parts": v.parts, "repaired": v.repaired,
                  "skipped": v.skipped, "triangles": model.triangles}
    else:
        from mitsuforest.pipeline import render   # noqa: F401  (imports as a render would)
        from mitsuforest.config import load_scene
        from mitsuforest.survey import prepare
        scene = load_scene(_scene_file(path, copies), variant="llvm_ad_mono")
        built = prepare(scene).scan_scene
        result = {"objects": built.objects, "distinct_triangles": built.triangles}
    result["seconds"] = round(time.perf_counter() - t0, 2)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    result["cpu_seconds"] = round(usage.ru_utime + usage.ru_stime, 2)   # includes the imports
    result["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return result


def _scene_file(path: Path, copies: int) -> Path:
    import yaml
    side = float(np.ceil(np.sqrt(copies)) * 12)
    data = {"name": "big", "seed": 1, "area": {"size": [side, side]},
            "forest": {"trees": copies, "archetypes": [], "min_spacing": 6,
                       "models": [{"mesh": str(path), "units": "cm", "up": "y", "leaves": ["leaf*"]}]},
            "understory": {"bushes": 0, "rocks": 0, "deadwood": 0, "stumps": 0},
            "sensor": str(ROOT / "sensors" / "ideal.yaml"),
            "survey": {"altitude": 60, "pulse_frequency": 100000, "lines": [[[0, side / 2], [side, side / 2]]]},
            "simulation": {"variant": "llvm_ad_mono"}}
    scene = path.with_name(f"scene_{copies}.yaml")
    scene.write_text(yaml.safe_dump(data))
    return scene


def _in_child(args: list[str], cache: Path) -> dict:
    env = {**os.environ, "MITSUFOREST_CACHE": str(cache), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, env=env)
    if proc.returncode:
        raise SystemExit(proc.stderr[-3000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--triangles", type=int, default=2_000_000)
    p.add_argument("--copies", type=int, nargs="+", default=[1, 40])
    p.add_argument("--quick", action="store_true", help="30,000 triangles, 1 and 3 copies (for CI)")
    p.add_argument("--out", type=Path, help="folder for the mesh (default: a temporary folder)")
    p.add_argument("--stage", help=argparse.SUPPRESS)
    p.add_argument("--mesh", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.stage:
        print(json.dumps(stage(args.stage, args.mesh, args.copies[0])))
        return
    if args.quick:
        args.triangles, args.copies = 30_000, [1, 3]
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        mesh = folder / "big_tree.obj"
        t0 = time.perf_counter()
        info = write_big_tree(mesh, args.triangles)
        print(f"wrote {mesh.name}: {info['wood_triangles']:,} wood triangles in {info['wood_parts']} parts, "
              f"{info['leaf_triangles']:,} leaf triangles, {info['file_mb']} MB ({time.perf_counter() - t0:.1f} s)")
        cache = Path(tmp) / "cache"
        build = _in_child(["--stage", "build", "--mesh", str(mesh)], cache)
        print(f"load + split + repair + union (cold cache): {build['seconds']:.1f} s ({build['cpu_seconds']:.1f} s of "
              f"CPU in the process, imports included), peak memory "
              f"{build['peak_rss_mb']:.0f} MB; {build['triangles']:,} triangles, {build['parts']} wood parts in the "
              f"volume ({build['repaired']} repaired, {build['skipped']} skipped), union {build['union_m3']:.6f} m3, "
              f"naive sum {build['naive_m3']:.6f} m3")
        cached = _in_child(["--stage", "cached", "--mesh", str(mesh)], cache)
        print(f"from the cache: {cached['seconds']:.2f} s (file hashed and model loaded), peak memory "
              f"{cached['peak_rss_mb']:.0f} MB")
        for copies in args.copies:
            scene = _in_child(["--stage", "scene", "--mesh", str(mesh), "--copies", str(copies)], cache)
            print(f"scene with {copies} placed copies: {scene['objects']} objects, {scene['distinct_triangles']:,} "
                  f"distinct triangles, {scene['seconds']:.1f} s, peak memory {scene['peak_rss_mb']:.0f} MB")
    load = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, {platform.platform()}; "
          f"load average {load:.1f} at the end (wall times grow with it, CPU times much less)")


if __name__ == "__main__":
    main()
