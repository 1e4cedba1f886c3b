"""Your own trees: a forest mixing procedural archetypes, a mesh tree and a QSM tree (README, "Your own trees").

    python examples/own_models.py [--out out/examples/own_models] [--quick] [--write-data]

``examples/own_models.yaml`` places them. Its two tree files are in ``examples/data/`` and this script
wrote them (``--write-data`` writes them again, byte for byte):

- ``sapling_tree.obj`` (+ ``.mtl``): a tree mesh as modelling tools export it: Y-up, centimetres,
  one object per branch with material ``bark``, leaves with material ``leaf``. Four branches have an
  open end (their cap is missing) and one has its faces inside out, to show the repair.
- ``small_qsm.txt``: a TreeQSM-style cylinder table (tab-separated, TreeQSM's header).

Both come from procedural skeletons, so their true wood volume is known: the script prints the
repair report, the volumes, and the points each imported tree got in the scan.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from common import ROOT, load_render, read_csv

from mitsuforest.specs.archetypes import Archetype
from mitsuforest.trees.leaves import leaves_on_twigs
from mitsuforest.trees.skeleton import grow, terminal_branches
from mitsuforest.trees.tubes import tube
from mitsuforest.trees.volume import union_volume

DATA = ROOT / "examples" / "data"
MESH_TREE = Archetype(height=9.0, dbh=0.16, crown_diameter=5.0, crown_ratio=0.5, branches=8, children=3, twigs=0,
                      leaf_area=5.0, leaf_length=0.12, leaf_width=0.03, seed=21)
QSM_TREE = Archetype(height=12.0, dbh=0.2, crown_diameter=6.0, crown_ratio=0.5, branches=10, children=3, twigs=0,
                     seed=22)
OPEN_ENDS, INSIDE_OUT = (2, 5, 8, 11), 7      # branches written with a missing end cap / inverted faces


def mesh_tree_tubes():
    """The mesh tree's branches as closed tubes (the generator's truth), and its leaves."""
    branches = grow(MESH_TREE)
    twigs = [b.points for b in terminal_branches(branches)]
    leaves = leaves_on_twigs(twigs, MESH_TREE.leaf_area, MESH_TREE.leaf_length, MESH_TREE.leaf_width,
                             MESH_TREE.leaf_inclination, MESH_TREE.leaf_clumping, np.random.default_rng(1))
    return [tube(b.points, b.radii) for b in branches], leaves


def write_mesh_tree(path) -> None:
    tubes, (leaf_v, leaf_f) = mesh_tree_tubes()
    lines, base = ["# mitsuforest examples/own_models.py: a tree mesh, Y-up, centimetres", "mtllib sapling_tree.mtl"], 1
    pieces = []
    for k, (v, f) in enumerate(tubes):
        sides = int(np.sum(f == len(v) - 1))    # faces around the end-cap centre (the last vertex)
        if k in OPEN_ENDS:
            v, f = v[:-1], f[:-sides]
        if k == INSIDE_OUT:
            f = f[:, ::-1]
        pieces.append((f"Branch_{k:02d}" if k else "Trunk", "bark", v, f))
    pieces.append(("Leaves", "leaf", leaf_v, leaf_f))
    for name, material, v, f in pieces:
        cm = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]) * 100.0    # z-up metres to Y-up centimetres
        lines += [f"o {name}", f"usemtl {material}"] + [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in cm]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in f]
        base += len(v)
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".mtl").write_text("newmtl bark\nKd 0.35 0.25 0.18\nnewmtl leaf\nKd 0.2 0.45 0.15\n")


def write_qsm(path) -> None:
    """One cylinder per skeleton segment, with the frustum's volume; parents and branches as TreeQSM numbers them."""
    branches = grow(QSM_TREE)
    rows, first_row = [], []
    for b_index, b in enumerate(branches, start=1):
        first_row.append(len(rows))
        r0, r1 = b.radii[:-1], b.radii[1:]
        radius = np.sqrt((r0 * r0 + r0 * r1 + r1 * r1) / 3)
        for i, (p, q, r) in enumerate(zip(b.points[:-1], b.points[1:], radius)):
            length = float(np.linalg.norm(q - p))
            parent = len(rows) if i else _nearest_cylinder(rows, p, b.order)
            rows.append([r, length, *p, *((q - p) / length), parent, 0, b_index, b.order, i + 1])
    for k, row in enumerate(rows):
        nxt = k + 2 if k + 1 < len(rows) and rows[k + 1][10] == row[10] else 0
        row[9] = nxt
    header = "radius (m)\tlength (m)\tstart_point\t\t\taxis_direction\t\t\tparent\textension\tbranch\tbranch_order\t" \
             "position_in_branch"
    text = [header] + ["\t".join(_cells(row)) for row in rows]
    path.write_text("\n".join(text) + "\n")


def _nearest_cylinder(rows, point, order) -> int:
    """1-based number of the cylinder of a lower order whose axis passes nearest ``point`` (0: none)."""
    best, best_d = 0, np.inf
    for k, row in enumerate(rows):
        if row[11] >= order:
            continue
        start, axis, length = np.array(row[2:5]), np.array(row[5:8]), row[1]
        t = np.clip(np.dot(point - start, axis), 0, length)
        d = np.linalg.norm(start + t * axis - point)
        if d < best_d:
            best, best_d = k + 1, d
    return best


def _cells(row) -> list[str]:
    """Radius, length, start and axis as decimals; the numbers after them as integers."""
    return [f"{round(x, 6) + 0.0:.6f}" for x in row[:8]] + [str(int(x)) for x in row[8:]]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", type=Path, default=ROOT / "examples" / "own_models.yaml", help="scene file")
    p.add_argument("--out", type=Path, default=ROOT / "out" / "examples" / "own_models", help="output folder")
    p.add_argument("--quick", action="store_true", help="one flight leg at 100 kHz and 7 sub-rays (for CI)")
    p.add_argument("--write-data", action="store_true", help="write examples/data/ again before rendering")
    args = p.parse_args()
    if args.write_data:
        write_mesh_tree(DATA / "sapling_tree.obj")
        write_qsm(DATA / "small_qsm.txt")
    points, scene, folder = load_render(args.scene, args.out, args.quick)
    manifest = json.loads((folder / f"{scene.name}_manifest.json").read_text())
    for name, info in manifest["imported_trees"].items():
        v = info["volume_m3"]
        print(f"{name} ({info['source']}): {info['height_m']:.2f} m tall, {info['triangles']:,} triangles; wood "
              f"union {v['union']:.5f} m3, naive sum {v['naive']:.5f} m3"
              + (f", cylinder sum {v['analytic']:.5f} m3" if v["analytic"] is not None else "")
              + f"; parts: {v['parts']} in the volume, {v['repaired']} repaired, {v['skipped']} skipped")
        for r in info["repair"]:
            print(f"  part {r['part']:>2} ({r['piece']}): {r['action']:<10} {r['reason']:<20} faces {r['faces_before']} -> "
                  f"{r['faces_after']} (+{r['faces_added']} -{r['faces_removed']}), volume after {r['volume_after']:.6f} m3")
    truth = union_volume(mesh_tree_tubes()[0])
    mesh = next(i for i in manifest["imported_trees"].values() if i["source"].endswith(".obj"))
    print(f"mesh tree: union after repair {mesh['volume_m3']['union']:.6f} m3, the generator's closed tubes "
          f"{truth:.6f} m3 (relative difference {mesh['volume_m3']['union'] / truth - 1:.1e}; the OBJ keeps 1 µm)")
    ids = {int(r["object_id"]): r for r in read_csv(folder / f"{scene.name}_ids.csv")}
    imported = {int(r["treeid"]) for r in ids.values() if r["source"]}
    for treeid in sorted(imported):
        sel = points["treeid"] == treeid
        wood = int(np.sum(sel & (points["classification"] == 2)))
        print(f"treeid {treeid}: {int(sel.sum()):,} points ({wood:,} wood, {int(sel.sum()) - wood:,} leaves) on "
              f"{len(np.unique(points['instance'][sel]))} placed copies, "
              f"{len(np.unique(points['object_id'][sel]))} distinct object ids")


if __name__ == "__main__":
    main()
