"""Leaf-wood classification: split a render into wood (class 2) and leaves (3), then train a baseline.

Features per point are simple and local: height above ground, intensity, return number and count,
and the eigenvalue shape of its 20 nearest neighbours (linearity, planarity, scattering, verticality).
A random forest (scikit-learn) is trained on half of the trees and tested on the others.

    python examples/leaf_wood.py [--scene scenes/demo.yaml] [--out out/examples/leaf_wood] [--quick]
"""

import numpy as np
from common import arguments, load_render
from scipy.spatial import cKDTree

args = arguments(__doc__, "leaf_wood")
points, scene, folder = load_render(args.scene, args.out, args.quick)
tree = points[np.isin(points["classification"], [2, 3])]
wood = tree["classification"] == 2
print(f"{len(tree):,} tree points: {wood.mean():.1%} wood, {1 - wood.mean():.1%} leaves")
for inst in np.unique(tree["instance"]):
    sel = tree["instance"] == inst
    print(f"  tree instance {inst} (archetype {tree['treeid'][sel][0]}): {sel.sum():,} points, "
          f"wood fraction {wood[sel].mean():.1%}")

# Local geometric features.
xyz = np.column_stack([tree["x"], tree["y"], tree["z"]])
xyz -= xyz.mean(axis=0)
_, nbr = cKDTree(xyz).query(xyz, k=20)
local = xyz[nbr] - xyz[nbr].mean(axis=1, keepdims=True)
cov = np.einsum("nki,nkj->nij", local, local) / 20
values, vectors = np.linalg.eigh(cov)                     # ascending eigenvalues
l3, l2, l1 = (np.maximum(values[:, i], 1e-12) for i in range(3))
features = np.column_stack([
    tree["z"] - scene.origin.offset[2], np.log(tree["intensity"]), tree["return_number"],
    tree["number_of_returns"], (l1 - l2) / l1, (l2 - l3) / l1, l3 / l1, 1 - np.abs(vectors[:, 2, 2])])
labels = wood.astype(int)

from sklearn.ensemble import RandomForestClassifier  # noqa: E402  (optional dependency: pip install ".[examples]")
from sklearn.metrics import confusion_matrix  # noqa: E402

instances = np.unique(tree["instance"])
train = np.isin(tree["instance"], instances[::2])          # train on every other tree, test on the rest
model = RandomForestClassifier(n_estimators=60, max_depth=12, n_jobs=2, random_state=0)
model.fit(features[train], labels[train])
predicted = model.predict(features[~train])
truth = labels[~train]
matrix = confusion_matrix(truth, predicted, labels=[0, 1])
iou = [matrix[c, c] / (matrix[c].sum() + matrix[:, c].sum() - matrix[c, c]) for c in (0, 1)]
print(f"test trees {len(instances[1::2])}: accuracy {np.mean(predicted == truth):.3f}, "
      f"IoU leaves {iou[0]:.3f}, IoU wood {iou[1]:.3f}")
print("confusion matrix (rows truth, columns predicted; leaves, wood):")
print(matrix)
args.out.mkdir(parents=True, exist_ok=True)
np.savetxt(args.out / "confusion_matrix.csv", matrix, fmt="%d", delimiter=",", header="leaves,wood")
print(f"wrote {args.out / 'confusion_matrix.csv'}")
