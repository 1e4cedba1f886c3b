"""The paper's three 1 ha forests at full size: time per stage, throughput, density, memory.

Each scene is rendered by the CLI in a child process (so its peak memory is measured alone) and the
figures come from its manifest, next to the Synthetic Forest paper's Table 3.

    python benchmarks/full_scenes.py                       # woodland, open, closed (long: see RESULTS.md)
    python benchmarks/full_scenes.py open --beam-samples 1 --beam-pattern fixed   # thin beam
    python benchmarks/full_scenes.py --quick               # 20 m x 20 m versions, one leg (CI)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PAPER = {"woodland": (70, 38, 3302), "open": (121, 63, 3593), "closed": (216, 84, 3862)}  # trees, cover %, pts/m²


# The CLI in a child process that reports its own peak resident memory.
CHILD = ("import resource, sys\nfrom mitsuforest.cli import main\ncode = main(sys.argv[1:])\n"
         "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\nsys.exit(code)")


def scene_copy(name: str, folder: Path, beam_samples: int | None, quick: bool, beam_pattern: str | None = None,
               formats=("pcd", "laz")) -> Path:
    """The scene file with absolute paths, optionally changed (sub-rays; a 20 m quick version)."""
    src = ROOT / "scenes" / f"{name}.yaml"
    data = yaml.safe_load(src.read_text())
    data["sensor"] = str((src.parent / data["sensor"]).resolve())
    data.setdefault("simulation", {})
    if beam_samples:
        data["simulation"]["beam_samples"] = beam_samples
    if beam_pattern:
        data["simulation"]["beam_pattern"] = beam_pattern
    if quick:
        data["area"] = {"size": [20, 20]}
        data["forest"]["trees"] = max(PAPER[name][0] // 25, 1)
        data["understory"] = {k: max(v // 25, 1) for k, v in data["understory"].items()}
        data["survey"]["lines"] = [[[10, -2], [10, 22]]]
        data["survey"]["pulse_frequency"] = 100000
    data["output"] = {"dir": str(folder / name), "formats": list(formats)}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run(name: str, folder: Path, beam_samples, quick: bool, keep_manifest: Path | None = None,
        beam_pattern: str | None = None, formats=("pcd", "laz")) -> dict:
    path = scene_copy(name, folder, beam_samples, quick, beam_pattern, formats)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", CHILD, "render", str(path), "--overwrite", "--quiet"],
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{name}: render failed:\n{proc.stderr}")
    peak_mb = int(proc.stderr.rsplit("PEAK_RSS_KB", 1)[1].split()[0]) / 1024
    m = json.loads((folder / name / f"{name}_manifest.json").read_text())
    sizes = {f: (folder / name / f"{name}.{f}").stat().st_size for f in formats}
    if keep_manifest:
        keep_manifest.mkdir(parents=True, exist_ok=True)
        (keep_manifest / f"{name}_manifest.json").write_text(json.dumps(m, indent=1))
    scan_s = m["timings_s"]["scan"]
    return {
        "scene": name, "trees": m["scene"]["forest"]["trees"],
        "canopy_cover": m["canopy_cover"], "wall_s": wall, "timings_s": m["timings_s"],
        "pulses_cast": m["pulses"]["cast"], "pulses_per_s": m["pulses"]["cast"] / scan_s,
        "points": m["points"], "points_per_s": m["points"] / scan_s, "density_per_m2": m["density_per_m2"],
        "mean_spacing_m": m["mean_spacing_m"], "returns_histogram": m["returns_histogram"],
        "peak_rss_mb": peak_mb, "beam_samples": m["scene"]["simulation"]["beam_samples"],
        "variant": m["variant"], "classes": m.get("classes"), "file_bytes": sizes,
    }


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="*", default=list(PAPER), help="woodland, open, closed (default: all three)")
    p.add_argument("--beam-samples", type=int, help="override the scenes' simulation.beam_samples")
    p.add_argument("--beam-pattern", choices=["fixed", "stratified"], help="override simulation.beam_pattern")
    p.add_argument("--formats", nargs="+", default=["pcd", "laz"], choices=["pcd", "las", "laz"])
    p.add_argument("--quick", action="store_true", help="20 m x 20 m versions, one leg")
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "out")
    args = p.parse_args(argv)
    unknown = set(args.scenes) - set(PAPER)
    if unknown:
        p.error(f"unknown scene(s) {', '.join(sorted(unknown))}; choose from {', '.join(PAPER)}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes:
            row = run(name, Path(tmp), args.beam_samples, args.quick, args.out, args.beam_pattern, args.formats)
            rows.append(row)
            t = row["timings_s"]
            print(f"{name}: {row['wall_s']:.0f} s end to end (plan {t['plan']:.1f}, trees {t['trees']:.1f}, "
                  f"scene {t['scene']:.1f}, scan {t['scan']:.0f}, write {t['write']:.1f}); "
                  f"{row['pulses_per_s']:,.0f} pulses/s, {row['points_per_s']:,.0f} points/s; "
                  f"{row['points']:,} points, {row['density_per_m2']:.0f} pts/m2 (paper {PAPER[name][2]}), "
                  f"spacing {row['mean_spacing_m'] * 100:.2f} cm, cover {row['canopy_cover']:.1%} "
                  f"(paper {PAPER[name][1]} %), peak memory {row['peak_rss_mb']:,.0f} MB; "
                  f"returns {row['returns_histogram']}; files "
                  + ", ".join(f"{f} {b / 1e9:.2f} GB" for f, b in row["file_bytes"].items()), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "full_scenes.json").write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    main()
