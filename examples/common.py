"""Shared by the examples: render a scene once (or reuse its files) and read the points back."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

import mitsuforest as mf

ROOT = Path(__file__).resolve().parents[1]


def arguments(description: str, default_out: str) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--scene", type=Path, default=ROOT / "scenes" / "demo.yaml", help="scene file (default: demo)")
    p.add_argument("--out", type=Path, default=ROOT / "out" / "examples" / default_out, help="output folder")
    p.add_argument("--quick", action="store_true", help="one flight leg at 100 kHz and 7 sub-rays (for CI)")
    return p.parse_args()


def load_render(scene_file: Path, out: Path, quick: bool = False) -> tuple[np.ndarray, dict, Path]:
    """Points (PCD fields, georeferenced), the scene, and the render folder; renders only if needed (a
    quick render has a folder of its own, so that a full run never reads its points, nor the reverse)."""
    scene = mf.load_scene(scene_file, output_dir=out / ("render-quick" if quick else "render"))
    if quick:
        w, h = scene.area.size
        scene = scene.with_({"survey.lines": [[[w / 2, -2.0], [w / 2, h + 2.0]]], "survey.pulse_frequency": 100000,
                             "simulation.beam_samples": 7})
    folder = Path(scene.output.dir)
    if not (folder / f"{scene.name}_manifest.json").exists():
        mf.render(scene, progress=False, log=lambda *_: None)
    return mf.read_pcd(folder / f"{scene.name}.pcd"), scene, folder


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
