"""The whole pipeline from Python, without the command line: what a notebook user would write.

    python examples/python_api.py [--scene scenes/demo.yaml] [--out out/examples/python_api] [--quick]
"""

import numpy as np
from common import arguments

import mitsuforest as mf

args = arguments(__doc__, "python_api")

scene = mf.load_scene(args.scene, output_dir=args.out)   # a validated dict; every default filled in
scene["survey"]["altitude"] = 40                          # change anything, then plan
scene["understory"]["bushes"] = 3
if args.quick:
    scene["survey"]["lines"] = [[[10.0, -2.0], [10.0, 22.0]]]
    scene["simulation"]["beam_samples"] = 7

plan = mf.make_plan(scene)                                # deterministic placement, JSON-ready
trees = [o for o in plan["objects"] if o["kind"] == "tree"]
print(f"{len(trees)} trees, canopy cover {plan['canopy_cover']:.1%}; first tree at {np.round(trees[0]['position'], 2)}")

result = mf.render(scene, write=False, progress=False)    # write=True also writes every file
pts = result.points                                       # a numpy structured array
print(f"{len(pts):,} points with fields {pts.dtype.names}")
xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
wood = pts["classification"] == 2
print(f"wood points: {wood.sum():,}; their mean height {xyz[wood, 2].mean():.1f} m")
print(f"density {result.manifest['density_per_m2']:.0f} points/m2, "
      f"returns per pulse {result.manifest['returns_histogram']}")
