"""The same small scene scanned with every sensor in sensors/: density, returns, classes and time.

Each sensor flies the scene's survey at its pulse frequency nearest 200 kHz and its scan frequency
nearest 50 Hz (a Risley sensor ignores the scan frequency), no lower than one and a half times its
minimum range (an airborne scanner such as the Leica ALS50-II sees nothing nearer than 200 m).

    python examples/sensors.py [--scene scenes/demo.yaml] [--out out/examples/sensors] [--quick]
"""

import time

import numpy as np
from common import ROOT, arguments

import mitsuforest as mf

args = arguments(__doc__, "sensors")
rows = []
for path in sorted((ROOT / "sensors").glob("*.yaml")):
    sensor = mf.load_sensor(path)
    scene = mf.load_scene(args.scene, output_dir=args.out / path.stem)
    # None: the sensor's pulse frequency nearest 200 kHz and scan frequency nearest 50 Hz (Scene properties).
    altitude = max(scene.survey.altitude, 1.5 * sensor.range_min)
    scene = scene.with_(sensor=sensor, survey={"pulse_frequency": None, "scan_frequency": None, "altitude": altitude})
    if args.quick:
        w, h = scene.area.size
        scene = scene.with_({"survey.lines": [[[w / 2, 0.0], [w / 2, h]]], "simulation.beam_samples": 7})
    start = time.perf_counter()
    result = mf.render(scene, write=False, progress=False, log=lambda *_: None)
    seconds = time.perf_counter() - start
    m, pts = result.manifest, result.points
    classes = {name: np.mean(pts["classification"] == code) for code, name in
               ((1, "ground"), (2, "wood"), (3, "leaves"))}
    hist = m["returns_histogram"]
    rows.append(f"| {sensor.name} | {altitude:g} m | {scene.pulse_frequency / 1000:g} kHz | {m['points']:,} | "
                f"{m['density_per_m2']:,.0f} | {' / '.join(str(hist.get(k, 0)) for k in range(1, 5))} | "
                + " / ".join(f"{v:.0%}" for v in classes.values()) + f" | {seconds:.1f} s |")
table = ["| sensor | altitude | pulse rate | points | points/m² | pulses with 1/2/3/4 returns | ground / wood / leaves "
         "| time |",
         "| --- | --- | --- | --- | --- | --- | --- | --- |"] + rows
print("\n".join(table))
args.out.mkdir(parents=True, exist_ok=True)
(args.out / "sensors.md").write_text("\n".join(table) + "\n")
print(f"wrote {args.out / 'sensors.md'}")
