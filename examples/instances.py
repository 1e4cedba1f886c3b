"""Tree instances: keep tree points (tree wood and leaves), colour them by instance, measure each tree.

Writes a per-tree table (points, height, crown diameter) and a side view coloured by instance,
like the Synthetic Forest paper's Figure 5.

    python examples/instances.py [--scene scenes/demo.yaml] [--out out/examples/instances] [--quick]
"""

import numpy as np
from common import arguments, load_render
from PIL import Image

from mitsuforest.classes import TREE_LEAVES, TREE_WOOD
from mitsuforest.write.quicklook import instance_colours

args = arguments(__doc__, "instances")
points, scene, folder = load_render(args.scene, args.out, args.quick)
# By class, not treeid: tree models are numbered past ten (unique trees, a tree list), deadwood after them.
trees = points[np.isin(points["classification"], [TREE_WOOD, TREE_LEAVES])]
ground_z = np.median(points["z"][points["classification"] == 1])
rows = ["instance,treeid,points,height_m,crown_diameter_m"]
for inst in np.unique(trees["instance"]):
    t = trees[trees["instance"] == inst]
    leaves = t[t["classification"] == 3]
    xy = np.column_stack([leaves["x"], leaves["y"]]) if len(leaves) else np.column_stack([t["x"], t["y"]])
    span = np.percentile(xy, 98, axis=0) - np.percentile(xy, 2, axis=0)
    rows.append(f"{inst},{t['treeid'][0]},{len(t)},{t['z'].max() - ground_z:.2f},{span.mean():.2f}")
print("\n".join(rows))

# Side view from the south: x against z, nearest points drawn last.
scale = 25  # pixels per metre
x0, z0 = trees["x"].min(), ground_z
w, h = int((trees["x"].max() - x0) * scale) + 2, int((trees["z"].max() - z0) * scale) + 2
image = np.full((h, w, 3), 255, np.uint8)
order = np.argsort(-trees["y"])
i = ((trees["x"][order] - x0) * scale).astype(int)
j = h - 1 - ((trees["z"][order] - z0) * scale).astype(int).clip(0, h - 1)
image[j, i] = instance_colours(trees["instance"])[order]
args.out.mkdir(parents=True, exist_ok=True)
Image.fromarray(image).save(args.out / "instances_side.png")
(args.out / "trees.csv").write_text("\n".join(rows) + "\n")
print(f"wrote {args.out / 'trees.csv'} and {args.out / 'instances_side.png'}")
