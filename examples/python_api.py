"""The whole pipeline from Python, without the command line: what a notebook user would write.

    python examples/python_api.py [--scene scenes/demo.yaml] [--out out/examples/python_api] [--quick]
"""

import numpy as np
from common import arguments

import mitsuforest as mf

args = arguments(__doc__, "python_api")

scene = mf.load_scene(args.scene, output_dir=args.out)   # a frozen, validated Scene; every default filled in
scene = scene.with_({"survey.altitude": 40}, understory={"bushes": 3})   # edits are checked like the file
if args.quick:
    scene = scene.with_({"survey.lines": [[[10.0, -2.0], [10.0, 22.0]]], "simulation.beam_samples": 7})
print(f"{scene.sensor.name}: {scene.pulse_frequency:g} Hz, detection threshold {scene.sensor.detection_threshold:.2g}")

plan = mf.make_plan(scene)                                # deterministic placement; plan.to_json() for a file
trees = plan.trees
print(f"{len(trees)} trees, canopy cover {plan.canopy_cover:.1%}; first tree at {np.round(trees[0].position, 2)}")

result = mf.render(scene, write=False, progress=False)    # write=True also writes every file
pts = result.points                                       # a numpy structured array
print(f"{len(pts):,} points with fields {pts.dtype.names}")
xyz = np.column_stack([pts["x"], pts["y"], pts["z"]])
wood = pts["classification"] == 2
print(f"wood points: {wood.sum():,}; their mean height {xyz[wood, 2].mean():.1f} m")
print(f"density {result.manifest['density_per_m2']:.0f} points/m2, "
      f"returns per pulse {result.manifest['returns_histogram']}")
