"""Wood volume: join each tree's woody points with its true volume, and try a point-based estimate.

For every placed tree, the ground truth is the union volume of its archetype in <name>_volumes.csv.
From the points we measure height (top above ground) and DBH (a circle fitted to the stem points
between 1.2 and 1.4 m), and estimate volume = form factor 0.45 × basal area × height. The training
table (one row per tree) and a plot of the estimate against the truth are written.

    python examples/wood_volume.py [--scene scenes/demo.yaml] [--out out/examples/wood_volume] [--quick]
"""

import numpy as np
from common import arguments, load_render, read_csv

args = arguments(__doc__, "wood_volume")
points, scene, folder = load_render(args.scene, args.out, args.quick)
truth = {int(r["instance"]): r for r in read_csv(folder / f"{scene.name}_volumes.csv") if r["row"] == "tree"}
ground_z = np.median(points["z"][points["classification"] == 1])


def fit_circle(x, y):
    """Least-squares circle (Kasa fit): returns radius, or nan with too few points."""
    if len(x) < 6:
        return np.nan
    a = np.column_stack([x, y, np.ones_like(x)])
    c, *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    return float(np.sqrt(c[2] + (c[0] / 2) ** 2 + (c[1] / 2) ** 2))


rows = ["instance,treeid,wood_points,leaf_points,height_m,dbh_m,estimate_m3,true_volume_m3"]
estimates, volumes = [], []
for inst, row in truth.items():
    t = points[points["instance"] == inst]
    wood = t[t["classification"] == 2]
    height = t["z"].max() - ground_z if len(t) else np.nan
    breast = wood[np.abs(wood["z"] - ground_z - 1.3) < 0.1]
    dbh = 2 * fit_circle(breast["x"] - breast["x"].mean(), breast["y"] - breast["y"].mean()) if len(breast) else np.nan
    estimate = 0.45 * np.pi * (dbh / 2) ** 2 * height
    true = float(row["volume_union_m3"])
    rows.append(f"{inst},{row['treeid']},{len(wood)},{len(t) - len(wood)},{height:.2f},{dbh:.3f},{estimate:.4f},{true:.4f}")
    estimates.append(estimate)
    volumes.append(true)
print("\n".join(rows))
estimates, volumes = np.array(estimates), np.array(volumes)
ok = np.isfinite(estimates)
if ok.any():
    print(f"{ok.sum()} trees with a DBH fit: estimate / truth median {np.median(estimates[ok] / volumes[ok]):.2f}, "
          f"RMSE {np.sqrt(np.mean((estimates[ok] - volumes[ok]) ** 2)):.3f} m3")
args.out.mkdir(parents=True, exist_ok=True)
(args.out / "training_table.csv").write_text("\n".join(rows) + "\n")
try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.scatter(volumes[ok], estimates[ok])
    top = max(volumes.max(), np.nanmax(estimates, initial=0)) * 1.1
    ax.plot([0, top], [0, top], "k--", lw=0.8)
    ax.set_xlabel("true wood volume (m³, union)")
    ax.set_ylabel("0.45 · basal area · height (m³)")
    fig.tight_layout()
    fig.savefig(args.out / "estimate_vs_truth.png", dpi=110)
except ImportError:
    print("(matplotlib not installed: no plot)")
print(f"wrote {args.out / 'training_table.csv'}")
