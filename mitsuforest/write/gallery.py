"""``mitsuforest trees``: the archetypes' meshes, a volume table and a side-by-side picture."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import trimesh

from .. import seeds
from ..plan.types import ModelSpec
from ..trees import build_model
from .atomic import atomic_path, naming_errors, write_text
from .tables import csv_text


PIXELS_PER_M = 14    # trees.png's scale
GALLERY_FILE = re.compile(r"tree\d{2,}_(wood|leaves)\.ply|volumes\.csv|repairs\.csv|trees\.png")


def write_gallery(archetypes, folder, progress=print, models=()) -> list[dict]:
    """Write ``treeNN_wood.ply``, ``treeNN_leaves.ply``, ``volumes.csv`` and ``trees.png`` into ``folder``:
    the archetypes, then the imported ``models`` (``forest.models`` entries), numbered as a render
    numbers them. With imported meshes, ``repairs.csv`` lists every wood part the repair changed.

    Every model is built, then every file written into a staging folder and moved into place at the end,
    so a model that cannot be built, a failing write (a full disk, named) or Ctrl-C leaves the folder as it
    was; the files of an earlier gallery in ``folder`` are replaced, none left behind."""
    from . import Staging
    specs = [ModelSpec("tree", 0, archetype=a) for a in archetypes] + [ModelSpec("tree", 0, source=m) for m in models]
    built = []
    for i, spec in enumerate(specs):
        model = build_model(f"tree{i + 1:02d}", spec)
        v = model.volume
        progress(f"{model.name}: {v.union:.4f} m3 wood (union), {model.triangles:,} triangles"
                 + (f", {v.repaired} parts repaired, {v.skipped} skipped" if spec.source else ""))
        built.append((model, spec))
    staging = Staging(folder, "trees")
    rows = [_row(model, spec.archetype) for model, spec in built]
    earlier = [p.name for p in staging.folder.iterdir() if GALLERY_FILE.fullmatch(p.name) and p.is_file()]
    staging.commit_or_discard(lambda: _write_files(staging.path, built, rows), earlier)
    return rows


def _write_files(folder: Path, built, rows) -> None:
    repairs = [{"model": model.name, "source": model.meta["source"], **r}
               for model, _ in built for r in model.meta.get("repair", [])]
    for model, _ in built:
        for part in model.parts:
            path = folder / f"{model.name}_{part.name}.ply"
            with atomic_path(path) as tmp, naming_errors(path):
                trimesh.Trimesh(part.vertices, part.faces, process=False).export(tmp, file_type="ply")
    header = list(rows[0])
    write_text(folder / "volumes.csv", csv_text(header, [[_cell(r[k]) for k in header] for r in rows]))
    if repairs:
        write_text(folder / "repairs.csv", csv_text(list(repairs[0]), [[_cell(r[k]) for k in repairs[0]]
                                                                         for r in repairs]))
    names = [model.name + (f"\n{Path(model.meta.get('source', '')).name}" if spec.source else "")
             for model, spec in built]
    figure = gallery_figure([_side_picture(model) for model, _ in built], names)
    with atomic_path(folder / "trees.png") as tmp, naming_errors(folder / "trees.png"):
        figure.savefig(tmp, format="png", dpi=figure.dpi)


def _row(model, archetype) -> dict:
    v, a = model.volume, archetype
    return {"model": model.name, "height_m": a.height if a else model.meta["height"], "dbh_m": a.dbh if a else "",
            "volume_union_m3": v.union, "volume_analytic_m3": v.analytic, "volume_naive_m3": v.naive,
            "parts": v.parts, "wood_triangles": len(model.parts[0].faces),
            "leaf_triangles": sum(len(p.faces) for p in model.parts[1:]),
            "source": model.meta.get("source", ""), "parts_repaired": v.repaired, "parts_skipped": v.skipped}


def _cell(x):
    if isinstance(x, float):
        return "" if np.isnan(x) else f"{x:.9g}"
    return x


def _side_picture(model, pixels_per_m=PIXELS_PER_M, samples=250_000):
    """Surface samples of wood (brown) and leaves (green), seen from the side, as an RGB image."""
    rng = seeds.rng(0, "gallery")
    layers = []
    for part, colour in zip(model.parts, ([110, 70, 40], [70, 150, 60])):
        mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
        pts, _ = trimesh.sample.sample_surface(mesh, samples, seed=rng.integers(1 << 31))
        layers.append((pts, colour))
    allpts = np.vstack([p for p, _ in layers])
    (x0, _, z0), (x1, _, z1) = allpts.min(0), allpts.max(0)
    w, h = int((x1 - x0) * pixels_per_m) + 3, int((z1 - z0) * pixels_per_m) + 3
    img = np.full((h, w, 3), 255, np.uint8)
    for pts, colour in layers:
        i = ((pts[:, 0] - x0) * pixels_per_m).astype(int) + 1
        j = h - 2 - ((pts[:, 2] - z0) * pixels_per_m).astype(int)
        img[j, i] = colour
    return img


def gallery_figure(images, names, pixels_per_m=PIXELS_PER_M, gap=10):
    """The trees' side pictures (:func:`_side_picture`) side by side on their bases, each named under it,
    with a height axis in metres: a matplotlib :class:`~matplotlib.figure.Figure` at one pixel per
    picture pixel."""
    from matplotlib.figure import Figure
    h = max(im.shape[0] for im in images)
    w = sum(im.shape[1] for im in images) + gap * (len(images) + 1)
    canvas = np.full((h + 2 * gap, w, 3), 255, np.uint8)
    x, centres = gap, []
    for im in images:
        canvas[gap + h - im.shape[0]:gap + h, x:x + im.shape[1]] = im
        centres.append((x + im.shape[1] / 2) / pixels_per_m)
        x += im.shape[1] + gap
    fig = Figure(figsize=(w / 100 + 1.0, (h + 2 * gap) / 100 + 1.0), dpi=100, layout="constrained")
    ax = fig.add_subplot()
    ax.imshow(canvas, extent=(0, w / pixels_per_m, -gap / pixels_per_m, (h + gap) / pixels_per_m),
              interpolation="nearest")
    ax.set_xticks(centres, names, fontsize=8)
    ax.set(ylabel="height above the tree's base (m)",
           title=f"{len(images)} trees seen from the side: wood brown, leaves green")
    return fig
