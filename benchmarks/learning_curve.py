"""What the data is worth: a baseline leaf-wood classifier trained on 1, 2, 4 ... plots.

    python benchmarks/learning_curve.py             # 16 training and 4 test plots per condition (about 10 min, 2 cores)
    python benchmarks/learning_curve.py --quick     # 4 and 2 plots, 5,000 tree points each (CI)
    python benchmarks/learning_curve.py --plots 8   # train on 1, 2, 4 and 8 plots

Each plot is the 20 m demo scene (five trees and its understory) with its own seed, scanned along two
legs at 100 kHz with 7 sub-rays, rendered in memory. Two conditions share the plots' seeds: the ten
default Eucalyptus archetypes (a test plot's trees are the same ten models as the training plots', so
the test is optimistic), and unique trees (``{species: eucalyptus, unique: 5}``: every plot draws its
own five, so test trees were never seen). Per point: covariance eigenvalue features (linearity,
planarity, sphericity, verticality) within two radii, height above ground, intensity divided by the
median intensity of the plot's first-return ground echoes, return number and number of returns. A
scikit-learn HistGradientBoostingClassifier (balanced class weights) learns tree_wood against
tree_leaves on a sample of each plot's tree points; scores are balanced accuracy and wood F1 on the
held-out plots' tree points. The classifiers trained on all plots are then applied to the real UAV scan
``../shared/data/real/UAS_Clip.laz`` (skipped when absent): the share of its non-ground points they
call wood by height band above the ASPRS ground (class 2, interpolated). No labels exist there.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
from scipy.spatial import cKDTree
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.metrics import balanced_accuracy_score, f1_score

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mitsuforest.classes import GROUND, TREE_LEAVES, TREE_WOOD  # noqa: E402
from mitsuforest.config import load_scene  # noqa: E402
from mitsuforest.pipeline import render  # noqa: E402

TREES = 5                      # trees per plot (the demo's)
CONDITIONS = {"ten archetypes": "default",
              "unique trees": [{"species": "eucalyptus", "unique": TREES}]}
TRAIN_SEED, TEST_SEED = 1000, 2000   # plot i of the training set has seed 1000 + i; test plots 2000 + j
RADII = (0.3, 1.0)             # m: the two neighbourhoods
NEIGHBOURS = (24, 64)          # at most this many nearest points within each radius
BANDS = ((0, 2), (2, 5), (5, 10), (10, 20), (20, np.inf))   # m above ground
FEATURES = [f"{name}_{r:g}m" for r in RADII for name in ("linearity", "planarity", "sphericity", "verticality")] \
    + ["height_above_ground", "intensity_norm", "return_number", "number_of_returns"]
ASPRS_GROUND, ASPRS_NOISE = 2, 7


def real_scan() -> Path | None:
    for folder in (ROOT.parent / "shared" / "data" / "real", Path("/work/shared/data/real")):
        if (folder / "UAS_Clip.laz").is_file():
            return folder / "UAS_Clip.laz"
    return None


def plot_scene(seed: int, archetypes):
    """The demo plot with seed ``seed`` and the condition's trees, two legs at 100 kHz, 7 sub-rays."""
    scene = load_scene(ROOT / "scenes" / "demo.yaml", seed=seed)
    return scene.with_({"forest.archetypes": archetypes, "survey.pulse_frequency": 100_000,
                        "survey.lines": [[[6.0, -5.0], [6.0, 25.0]], [[14.0, 25.0], [14.0, -5.0]]],
                        "simulation.beam_samples": 7})


def eigen_features(kdtree: cKDTree, xyz: np.ndarray, query: np.ndarray, radius: float, k: int,
                   chunk: int = 50_000) -> np.ndarray:
    """(n, 4) linearity, planarity, sphericity and verticality of the covariance of the (at most ``k``)
    points of ``xyz`` within ``radius`` of each ``query`` point (n, 3); NaN with fewer than 3."""
    out = np.full((len(query), 4), np.nan)
    for start in range(0, len(query), chunk):
        q = query[start:start + chunk]
        d, idx = kdtree.query(q, k=k, distance_upper_bound=radius)
        valid = np.isfinite(d)
        count = valid.sum(1)
        pts = np.where(valid[..., None], xyz[np.minimum(idx, len(xyz) - 1)], 0.0)
        mean = pts.sum(1) / np.maximum(count, 1)[:, None]
        centred = np.where(valid[..., None], pts - mean[:, None], 0.0)
        cov = np.einsum("nki,nkj->nij", centred, centred) / np.maximum(count, 1)[:, None, None]
        w, v = np.linalg.eigh(cov)                      # ascending: l3 <= l2 <= l1
        l3, l2, l1 = np.clip(w[:, 0], 0, None), w[:, 1], np.maximum(w[:, 2], 1e-12)
        features = np.column_stack([(l1 - l2) / l1, (l2 - l3) / l1, l3 / l1, 1 - np.abs(v[:, 2, 0])])
        features[count < 3] = np.nan
        out[start:start + chunk] = features
    return out


def point_features(xyz, height, intensity, return_number, number_of_returns, first_ground, rows) -> np.ndarray:
    """(len(rows), len(FEATURES)) for the points ``rows`` of a cloud, neighbourhoods from all its points.
    Intensity is divided by the median of the cloud's first-return ground echoes (``first_ground``)."""
    kdtree = cKDTree(xyz)
    geometric = [eigen_features(kdtree, xyz, xyz[rows], r, k) for r, k in zip(RADII, NEIGHBOURS)]
    scale = np.median(intensity[first_ground]) if first_ground.any() else np.median(intensity)
    return np.column_stack([*geometric, height[rows], intensity[rows] / scale,
                            return_number[rows], number_of_returns[rows]]).astype(np.float32)


def synthetic_plot(seed: int, archetypes, tree_points: int):
    """Features and labels (1 wood, 0 leaves) of a sample of one rendered plot's tree points, and their heights."""
    result = render(plot_scene(seed, archetypes), write=False, progress=False, log=lambda *_: None)
    p = result.points
    xyz = np.column_stack([p["x"], p["y"], p["z"]]) - np.asarray(result.scene.origin.offset)
    height = xyz[:, 2] - result.plan.terrain.height(xyz[:, 0], xyz[:, 1])
    trees = np.flatnonzero(np.isin(p["classification"], (TREE_WOOD, TREE_LEAVES)))
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(trees, min(tree_points, len(trees)), replace=False))
    first_ground = (p["classification"] == GROUND) & (p["return_number"] == 1)
    x = point_features(xyz, height, p["intensity"].astype(float), p["return_number"], p["number_of_returns"],
                       first_ground, rows)
    return x, (p["classification"][rows] == TREE_WOOD).astype(np.int8), height[rows]


def classifier() -> HistGradientBoostingClassifier:
    return HistGradientBoostingClassifier(max_iter=200, learning_rate=0.1, class_weight="balanced", random_state=0)


def learning_curve(train, test, counts) -> tuple[list[tuple[int, float, float]], HistGradientBoostingClassifier]:
    """(plots, balanced accuracy, wood F1) for a classifier trained on the first ``n`` plots, each ``n``
    in ``counts``; and the classifier trained on the most."""
    x_test = np.vstack([x for x, _, _ in test])
    y_test = np.concatenate([y for _, y, _ in test])
    rows = []
    for n in counts:
        model = classifier().fit(np.vstack([x for x, _, _ in train[:n]]), np.concatenate([y for _, y, _ in train[:n]]))
        predicted = model.predict(x_test)
        rows.append((n, balanced_accuracy_score(y_test, predicted), f1_score(y_test, predicted)))
    return rows, model


def real_features(path: Path):
    """Features of the real scan's non-ground, non-noise points and their heights above the ASPRS ground."""
    import laspy
    las = laspy.read(path)
    xyz = np.column_stack([las.x, las.y, las.z]) - np.array([las.header.mins[0], las.header.mins[1], 0.0])
    cls = np.asarray(las.classification)
    ground = cls == ASPRS_GROUND
    linear = LinearNDInterpolator(xyz[ground, :2], xyz[ground, 2])
    z0 = linear(xyz[:, :2])
    missing = np.isnan(z0)
    z0[missing] = NearestNDInterpolator(xyz[ground, :2], xyz[ground, 2])(xyz[missing, :2])
    height = xyz[:, 2] - z0
    rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    rows = np.flatnonzero(~ground & (cls != ASPRS_NOISE))
    x = point_features(xyz, height, np.asarray(las.intensity, float), rn, nr, ground & (rn == 1), rows)
    return x, height[rows]


def band_shares(height, wood) -> list[tuple[str, int, float]]:
    out = []
    for lo, hi in BANDS:
        inside = (height >= lo) & (height < hi) if lo > 0 else height < hi
        out.append((f"{lo:g}-{hi:g} m" if np.isfinite(hi) else f"{lo:g}+ m", int(inside.sum()),
                    float(wood[inside].mean()) if inside.any() else float("nan")))
    return out


def figure(curves: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    for (name, rows), colour in zip(curves.items(), ("tab:orange", "tab:green")):
        n = [r[0] for r in rows]
        ax.plot(n, [r[1] for r in rows], "o-", color=colour, label=f"{name}: balanced accuracy")
        ax.plot(n, [r[2] for r in rows], "s--", color=colour, label=f"{name}: wood F1")
    ax.set_xscale("log", base=2)
    ax.set_xticks(n, [str(k) for k in n])
    ax.set_xlabel("training plots (20 m x 20 m, five trees each)")
    ax.set_ylabel("score on held-out plots (tree points)")
    ax.set_title("Leaf-wood classifier: learning curve")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _at_least_one(text: str) -> int:
    if not (text.isascii() and text.isdigit()) or int(text) < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return int(text)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plots", type=_at_least_one, default=16, help="training plots (the curve doubles up to it; default 16)")
    parser.add_argument("--test-plots", type=_at_least_one, default=4, help="held-out plots per condition (default 4)")
    parser.add_argument("--tree-points", type=_at_least_one, default=20_000, help="tree points sampled per plot (default 20,000)")
    parser.add_argument("--quick", action="store_true", help="4 training and 2 test plots, 5,000 tree points each")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "learning_curve.png", help="where the figure goes")
    parser.add_argument("--no-figure", action="store_true")
    parser.add_argument("--no-real", action="store_true", help="skip the real scan")
    args = parser.parse_args(argv)
    if not args.no_figure and not args.figure.parent.is_dir():
        parser.error(f"--figure: no folder {args.figure.parent} to write it into")
    if args.quick:
        args.plots, args.test_plots, args.tree_points = 4, 2, 5_000
    counts = [2 ** i for i in range(int(np.log2(max(args.plots, 1))) + 1)]
    wall, cpu = time.perf_counter(), time.process_time()
    curves, models, truth = {}, {}, None
    for name, archetypes in CONDITIONS.items():
        c = time.process_time()
        train = [synthetic_plot(TRAIN_SEED + i, archetypes, args.tree_points) for i in range(counts[-1])]
        test = [synthetic_plot(TEST_SEED + j, archetypes, args.tree_points) for j in range(args.test_plots)]
        rendered = time.process_time() - c
        curves[name], models[name] = learning_curve(train, test, counts)
        print(f"{name}: {len(train) + len(test)} plots rendered and featured in {rendered:.0f} CPU s, "
              f"trained in {time.process_time() - c - rendered:.0f} CPU s; tree points per plot "
              f"{len(train[0][1]):,}, wood share of test points {np.mean(np.concatenate([y for _, y, _ in test])):.4f}")
        if name == "unique trees":
            truth = band_shares(np.concatenate([h for _, _, h in test]), np.concatenate([y for _, y, _ in test]))
    print("\n| training plots | " + " | ".join(f"{n}: balanced accuracy | {n}: wood F1" for n in curves) + " |")
    print("| --- |" + " --- | --- |" * len(curves))
    for i, n in enumerate(counts):
        print(f"| {n} | " + " | ".join(f"{rows[i][1]:.3f} | {rows[i][2]:.3f}" for rows in curves.values()) + " |")
    if not args.no_figure:
        figure(curves, args.figure)
        print(f"\nwrote {args.figure}")
    path = None if args.no_real else real_scan()
    if path is None:
        print("\nreal scan: skipped (" + ("--no-real" if args.no_real else
              "../shared/data/real/UAS_Clip.laz not found") + ")")
    else:
        x, height = real_features(path)
        shares = {n: band_shares(height, m.predict(x)) for n, m in models.items()}
        print(f"\nreal scan {path.name}: {len(x):,} non-ground points; share called wood by height above ground "
              f"(classifiers trained on {counts[-1]} plots; synthetic truth: the unique-tree test plots' tree points)")
        print("| height band | points | " + " | ".join(f"wood, {n}" for n in shares) + " | synthetic truth: wood share |")
        print("| --- | --- |" + " --- |" * len(shares) + " --- |")
        for i, (band, points, _) in enumerate(band_shares(height, np.zeros(len(height)))):
            print(f"| {band} | {points:,} | " + " | ".join(f"{s[i][2]:.3f}" for s in shares.values())
                  + f" | {truth[i][2]:.3f} ({truth[i][1]:,} pts) |")
    print(f"\ntotal: {time.process_time() - cpu:.0f} CPU s, {time.perf_counter() - wall:.0f} s wall")


if __name__ == "__main__":
    main()
