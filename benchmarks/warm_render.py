"""A scene rendered several times in one process: the first run cold (imports done, but tree models,
kernels and the device still to set up), the others warm, as a worker that renders plot after plot
sees them. Each run's wall and CPU time, its stages, points per second and peak memory; with
``--manifest`` the last run's manifest is copied out (for ``benchmarks/agreement.py``).

    python benchmarks/warm_render.py scenes/open.yaml --variant cuda_ad_mono --dir /dev/shm
    python benchmarks/warm_render.py scenes/open.yaml --beam-samples 1 --beam-pattern fixed   # thin beam
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from mitsuforest.config import load_scene
from mitsuforest.pipeline import render


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", type=Path)
    p.add_argument("--runs", type=int, default=2)
    p.add_argument("--variant", default="auto")
    p.add_argument("--beam-samples", type=int)
    p.add_argument("--beam-pattern", choices=["fixed", "stratified"])
    p.add_argument("--dir", type=Path, help="where to write (default: the system's temporary folder)")
    p.add_argument("--manifest", type=Path, help="copy the last run's manifest here")
    args = p.parse_args(argv)
    changes = {f"simulation.{key}": value for key, value in
               (("beam_samples", args.beam_samples), ("beam_pattern", args.beam_pattern)) if value is not None}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        scene = load_scene(args.scene, variant=args.variant, output_dir=tmp).with_(changes)
        for run in range(args.runs):
            start, cpu = time.perf_counter(), time.process_time()
            manifest = render(scene, overwrite=True, progress=False, log=lambda *_: None).manifest
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            stages = ", ".join(f"{k} {v:.2f}" for k, v in manifest["timings_s"].items())
            print(f"{'cold' if run == 0 else 'warm'}: {wall:.1f} s wall, {cpu:.1f} s CPU, {manifest['points']:,} points "
                  f"({manifest['points'] / wall / 1e6:.2f} M/s), {manifest['variant']}; stages (s): {stages}; "
                  f"peak {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB", flush=True)
        if args.manifest:
            shutil.copy(Path(tmp) / f"{scene.name}_manifest.json", args.manifest)


if __name__ == "__main__":
    main()
