"""Writing a twin's scene folder: ``<name>.yaml``, ``<name>_dem.tif``, ``trees.csv``, ``twin.json`` (I/O).

The folder is written in a staging folder beside it and moved into place, so a failure leaves nothing
half-written.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from ..config import understory_capacity
from . import DEM_CELL, survey as survey_estimation

DEFAULT_SPECIES = "pinus_radiata"   # both real plots we twin are conifers
# The sensor a twin gets when the file does not say and --sensor is not given: the rates and field of view
# the survey needs (estimated), reach and intensity set for the survey, and the optics of a scanner with the
# file's mirror. A rotating mirror's are the RIEGL VUX-1UAV22's (sensors/riegl_vux-1uav22.yaml). Airborne
# scanners with an oscillating mirror (Leica ALS, Optech ALTM) fire at 1064 nm with a narrower beam and a
# longer pulse, and keep up to 4 returns a pulse, as MixedConifer's file does: theirs are the Leica
# ALS50-II's (sensors/leica_als50-ii.yaml). Uncalibrated, MixedConifer's twin had 39.6 % of its pulses
# single-return with the VUX's optics against the file's 69.3 % (returns_tv 0.297); with these, 65.9 % (0.063).
TWIN_OPTICS = {"rotating": "riegl_vux-1uav22", "oscillating": "leica_als50-ii"}   # built-in sensors, by mirror
OPTICS_KEYS = ("beam_divergence", "pulse_length", "wavelength", "range_precision", "range_accuracy", "max_returns",
               "echo_separation")   # what a twin's sensor takes from them
# The reach (m) and detection threshold of a UAV survey, the VUX-1UAV22's (a 20 % target detected at its
# reach); sensor_reach raises the one and lowers the other for a far survey.
TWIN_RANGE_MAX = 1000.0
TWIN_THRESHOLD = 2.0e-7
# The twin's sensor writes intensity as its amplitude scaled so that bare ground (the twin's ground reflectance)
# filling the beam at the survey's altitude and the file's median scan angle reads this many counts: fine steps
# (a 1e6 gain put a 127 m survey's ground at 16 counts, an 800 m one's at 0; here an echo of 1 % of the ground's
# reads 41) under 12 dB of headroom (a leaf-filled beam nearer than the ground, wood brighter: 2-3 times the
# ground at most). compare normalises intensity by the ground's median: the scale is the twin's own, not the file's.
GROUND_COUNTS = 4096
GROUND_THRESHOLD = 0.01   # the twin sensor detects echoes down to this share of bare ground's at nadir (sensor_reach)
DEFAULTS = {"altitude": 30.0, "speed": 2.0, "scan_frequency": 50.0, "field_of_view": 360.0, "line_spacing": 12.0,
            "heading": 0.0}
MARGIN = 10.0   # m: legs run this far beyond the plot
# The share of the plan's understory capacity a twin fills with bushes at most: random placement reached
# 0.79-0.90 of it on bare 8 x 30 to 100 x 100 m plots, and the twin's stems take room too.
BUSH_SHARE = 0.5
# The stand around the plot (forest.surround): out to where a pulse at the survey's widest scan angle (at
# most this) that reaches the plot's ground passes the height of its tallest tree, at most SURROUND_MAX m.
SURROUND_ANGLE, SURROUND_MAX = 70.0, 100.0
# The Pinus radiata templates with denser, fuller shoots: twice the whorl branches, 8 side shoots on each
# (against 4) with 4 twigs (against 2), each "leaf" a 30 x 3 cm shoot silhouette (against a 15 x 1.5 cm
# one), and the leaves spread through the crown's volume (``leaf_fill`` 1) rather than on the twigs. On the
# twigs of whorled branches the shoots pile into clumps with empty space between them, and more leaf area
# piles onto the same clumps: a 29 m twin tree's crown passed 0.40 -> 0.39 of the pulses at 2.5 times its
# leaf area, and the calibration measured a response exponent of 0.1 where Beer-Lambert's random leaves
# give 1. Spread through the volume they are a turbid medium, which shades as Beer-Lambert says (a small
# pine crown seen from above: its shadow within 2 % of it, against 0.44 of it on the twigs; tests/test_trees.py).
DENSE_SHOOTS = {"pinus_radiata": {"branches": 2.0, "children": 8, "twigs": 4, "leaf_clumping": 1.0,
                                   "leaf_length": 0.3, "leaf_width": 0.03, "leaf_fill": 1.0}}


def survey_plan(analysis: dict, sensor=None) -> tuple[dict, dict | str, dict]:
    """The scene's ``survey`` and ``sensor`` values, and per quantity its value and where it came from."""
    est: survey_estimation.SurveyEstimate = analysis["survey"]
    report = {}

    def pick(key, value):
        """The estimate, or the default with the reason there is none (both into the report)."""
        if value is not None:
            report[key] = {"value": value, "source": "estimated"}
            return value
        report[key] = {"value": DEFAULTS[key], "source": f"default ({est.missing.get(key, 'not estimated')})"}
        return DEFAULTS[key]

    altitude = pick("altitude", est.altitude)
    speed = pick("speed", est.speed)
    fov_seen = field_of_view_seen(est.field_of_view)
    deflector = est.deflector or "rotating"
    fired = (fov_seen or DEFAULTS["field_of_view"]) / 360.0 if deflector == "rotating" else 1.0   # pulses in the FOV
    if est.speed is None and est.pulse_frequency is not None:   # fly as fast as the file's pulse density asks
        speed = est.pulse_frequency * fired / (analysis["pulse_density"] * DEFAULTS["line_spacing"])
        report["speed"] = {"value": speed, "source": f"matched to the file's {analysis['pulse_density']:.2f} pulses/m² "
                           f"at the estimated pulse rate, {DEFAULTS['line_spacing']:g} m line spacing "
                           f"({est.missing.get('speed', 'not estimated')})"}
    scan_frequency = round(pick("scan_frequency", est.scan_frequency), 3)
    fov = pick("field_of_view", fov_seen)
    out = {"altitude": round(altitude, 2), "speed": round(speed, 3), "margin": MARGIN}
    spacing = _flight_lines(est, analysis["frame"], out, report)
    prf = _pulse_rate(est, analysis["pulse_density"], speed, spacing or DEFAULTS["line_spacing"], fired, report)
    if sensor is not None:
        return out | _rates_of(sensor, prf, scan_frequency, altitude, report), _sensor_value(sensor), report
    mirror = round(scan_frequency / lines_per_cycle(deflector), 3)   # turns, or cycles there and back
    scanner = built_in_optics(deflector)
    optics = twin_sensor(deflector, scanner)
    reach = sensor_reach(altitude, fov, optics["wavelength"])
    sensor_map = {**optics, **reach, "field_of_view": fov, "pulse_frequencies": [prf],
                  "scan_frequency_range": [min(10.0, mirror), max(200.0, mirror)],
                  "intensity": intensity_scale(altitude, analysis["scan_angle"], analysis["intensity_unit"][0],
                                               optics["wavelength"])}
    out["pulse_frequency"], out["scan_frequency"] = prf, mirror
    if deflector == "oscillating" and est.scan_frequency is not None:
        report["scan_frequency"] = {"value": mirror, "source": f"estimated: {scan_frequency:g} scan lines a second, "
                                    "swept there and back"}
    longer = f", its reach {reach['range_max']:g} m for a {altitude:.0f} m survey" \
        if reach["range_max"] > TWIN_RANGE_MAX else ""
    swept = (f"an oscillating mirror (sweeps both ways: {mirror:g} cycles a second)" if deflector == "oscillating"
             else "a rotating mirror" + ("" if est.deflector else f" (default: {est.missing.get('deflector', 'not estimated')})"))
    unit, why = analysis["intensity_unit"]
    written = {"reflectance_db": "the reflectance in dB, -25 to +5 dB onto 0-65535 (PDAL's map of RIEGL's reflectance)",
               "reflectance": f"the linear reflectance x {sensor_map['intensity']['gain']:.4g}",
               "amplitude": f"the amplitude x {sensor_map['intensity']['gain']:.4g}"}[unit]
    report["sensor"] = {"value": sensor_map["name"], "source": f"estimated rates and field of view, {swept}, the "
                        f"{scanner.name}'s optics{longer}; intensity: {written}, as {why}"}
    return out, sensor_map, report


def built_in_optics(deflector: str):
    """The built-in :class:`~mitsuforest.config.types.Sensor` whose optics a twin of a ``deflector``
    (``rotating`` or ``oscillating``) takes (:data:`TWIN_OPTICS`)."""
    from ..config import BUILTIN_SENSORS, load_sensor
    return load_sensor(BUILTIN_SENSORS / f"{TWIN_OPTICS[deflector]}.yaml")


def twin_sensor(deflector: str, scanner) -> dict:
    """The twin sensor's keys but its rates, field of view and intensity: the :data:`OPTICS_KEYS` the
    built-in sensor ``scanner`` sets (:func:`built_in_optics`), the reach and threshold of a UAV survey."""
    values = {k: getattr(scanner, k) for k in OPTICS_KEYS}
    optics = {k: list(v) if isinstance(v, tuple) else v for k, v in values.items() if v is not None}   # YAML-safe
    return {"name": f"twin sensor ({scanner.name} optics)", "deflector": deflector,
            "source": "mitsuforest twin: rates, field of view and mirror estimated from the scan, reach and "
                      f"intensity set for the survey (twin.json), the optics of the {scanner.name} "
                      f"(sensors/{TWIN_OPTICS[deflector]}.yaml: {scanner.source})",
            **optics,
            "range_min": 3.0, "range_max": TWIN_RANGE_MAX, "detection_threshold": TWIN_THRESHOLD}


def sensor_reach(altitude: float, field_of_view: float, wavelength: float = 1550e-9) -> dict:
    """The twin sensor's ``range_max`` and ``detection_threshold`` at ``wavelength`` (m). Those of a UAV
    survey (:data:`TWIN_RANGE_MAX`, the VUX-1UAV22's, a 20 % target detected there) where they serve; a
    survey whose longest slant range (at the half ``field_of_view``, at most :data:`SURROUND_ANGLE`) is more
    than half that reaches twice that range, and where that threshold is more than :data:`GROUND_THRESHOLD`
    of bare ground's echo at nadir from ``altitude``, the threshold is that: the VUX's own share at 128 m.
    An airborne scanner flown at 800 m detects such echoes (MixedConifer's weakest first returns, its 1st
    percentile, read 0.7 % of its ground's median intensity), where the VUX's threshold would drop every leaf
    echo that fills less than half the beam."""
    slant = altitude / math.cos(math.radians(min(field_of_view / 2, SURROUND_ANGLE)))
    reach = max(TWIN_RANGE_MAX, 10.0 * math.ceil(2 * slant / 10))
    ground = _ground_reflectance(wavelength)
    threshold = min(TWIN_THRESHOLD, GROUND_THRESHOLD * ground / max(altitude, 1.0) ** 2)
    return {"range_max": reach, "detection_threshold": float(f"{threshold:.4g}")}


def field_of_view_seen(widest: float | None) -> int | None:
    """The twin's field of view (whole degrees) from ``widest``, twice the file's largest scan angle,
    rounded up to 5°, within 5-360°: the angles a file keeps are a lower bound of its mirror's sweep, as
    deliveries trim swath edges where lines overlap. MixedConifer keeps ±18° (whole degrees), and its
    lines that lie inside the plot hold the twin's first returns a m² within 2 % at 40°, 11 % too many at
    36° (the same pulses over a narrower swath)."""
    return None if widest is None else int(min(360, 5 * max(1, math.ceil(widest / 5))))


def _ground_reflectance(wavelength: float) -> float:
    from ..classes import GROUND
    from ..scan.radiometry import reflectance_table
    return float(reflectance_table(wavelength)[GROUND])


def intensity_scale(altitude: float, scan_angle: float, unit: str = "amplitude",
                    wavelength: float = 1550e-9) -> dict:
    """The twin sensor's ``intensity`` mapping for a file whose intensity is ``unit``
    (:func:`~.intensity.intensity_unit`): for ``reflectance_db``, RIEGL's reflectance in dB as PDAL maps it
    (:data:`~mitsuforest.scan.radiometry.RIEGL_DB_MAP`); else the amplitude or the linear reflectance times
    the gain that puts bare ground at :data:`GROUND_COUNTS` (reflectance ρ at ``wavelength`` at scan angle ``a``:
    an amplitude of ``ρ cos³ a / altitude²``, a reflectance of ``ρ cos a``)."""
    if unit == "reflectance_db":
        from ..scan.radiometry import RIEGL_DB_MAP
        return dict(RIEGL_DB_MAP)
    cos = math.cos(math.radians(scan_angle))
    ground = _ground_reflectance(wavelength) * cos
    ground *= 1.0 if unit == "reflectance" else cos ** 2 / max(altitude, 1.0) ** 2
    return {"source": unit, "gain": float(f"{GROUND_COUNTS / ground:.4g}"), "offset": 0, "saturation": 65535}


def _flight_lines(est: survey_estimation.SurveyEstimate, frame, out: dict, report: dict) -> float | None:
    """The scan's own lines into ``out["lines"]`` where they were placed, else a lawnmower's spacing and
    heading; returns that spacing (m), or ``None`` for the scan's lines."""
    if est.line_positions and est.heading is not None:
        local = [survey_estimation.leg_ends(p, h, frame.bounds, MARGIN) for p, h in zip(est.line_positions, est.line_headings, strict=True)]
        out["lines"] = [[[round(a - frame.offset[0], 2), round(b - frame.offset[1], 2)] for a, b in leg] for leg in local]
        placed = {k: est.line_sources.count(k) for k in ("track", "scan angle", "scan lines", "not placed")}
        how = (f"{placed['scan lines']} where their scan lines' nadirs lie (no pulse with two returns)"
               if placed["scan lines"] else f"{placed['track']} on their tracks, {placed['scan angle']} by scan angle "
               "and beam side")
        why = "too few scan lines" if placed["scan lines"] else "too few pulses with two returns"
        report["lines"] = {"value": len(local), "source": f"estimated: of the file's {est.lines} lines, {how}, "
                           f"{placed['not placed']} not placed ({why})"}
        return None
    spacing = DEFAULTS["line_spacing"]
    out.update(line_spacing=spacing, heading=DEFAULTS["heading"])
    report["lines"] = {"value": "lawnmower", "source": f"default ({est.missing.get('lines', 'not estimated')}): "
                                                       f"{spacing:g} m apart, heading {DEFAULTS['heading']:g}"}
    return spacing


def _pulse_rate(est: survey_estimation.SurveyEstimate, pulse_density: float, speed: float, spacing: float,
                fired: float, report: dict) -> float:
    """The estimated pulse rate (Hz), or the one that gives the file's pulses per m² over parallel lines
    ``spacing`` m apart when the share ``fired`` of the pulses fire (a rotating mirror's FOV / 360), rounded
    to 100 Hz from 1 kHz up."""
    if est.pulse_frequency is not None:
        prf = est.pulse_frequency
        report["pulse_frequency"] = {"value": prf, "source": "estimated"}
    else:   # pulses per m² of parallel lines: PRF · fired / (speed · spacing)
        prf = pulse_density * speed * spacing / fired
        report["pulse_frequency"] = {"value": prf, "source": f"matched to the file's {pulse_density:.2f} "
                                     f"pulses/m² ({est.missing.get('pulse_frequency', 'not estimated')})"}
    return float(round(prf, -2)) if prf >= 1000 else float(round(prf))


def _sensor_value(sensor) -> str:
    """The scene's ``sensor:`` for the file ``sensor``: a built-in sensor's name, else its absolute path."""
    from ..config import BUILTIN_SENSORS, builtin_sensors
    path = Path(sensor).resolve()
    return path.stem if path.parent == BUILTIN_SENSORS.resolve() and path.stem in builtin_sensors() else str(path)


def _rates_of(sensor, prf: float, lines_per_second: float, altitude: float, report: dict) -> dict:
    """``--sensor``'s listed pulse rate nearest ``prf``, and its scan rate for the scan's lines per second
    within its range: an oscillating mirror's sweep there and back draws two lines, a turn one.

    :raises UserError: where the sensor sees nothing from the survey's ``altitude`` (its ``range_min``)."""
    from ..config import load_sensor
    from ..errors import UserError
    loaded = load_sensor(sensor)
    if altitude < loaded.range_min:
        raise UserError(f"--sensor: {loaded.name} sees nothing nearer than {loaded.range_min:g} m, and the "
                        f"scan was flown {altitude:.0f} m above its ground; give a sensor for that range")
    prf_listed = min(loaded.pulse_frequencies, key=lambda f: abs(f - prf))
    lo, hi = loaded.scan_frequency_range
    per_cycle = lines_per_cycle(loaded.deflector)
    report["sensor"] = {"value": _sensor_value(sensor), "source": "--sensor (its nearest pulse rate "
                        f"{prf_listed:g} Hz and scan rate within {lo:g}-{hi:g} Hz"
                        + (", half the lines per second: an oscillating mirror" if per_cycle == 2 else "") + ")"}
    return {"pulse_frequency": prf_listed, "scan_frequency": min(max(lines_per_second / per_cycle, lo), hi)}


def lines_per_cycle(deflector: str) -> int:
    """Scan lines a deflector draws per turn or cycle of its ``scan_frequency``: an oscillating mirror's
    sweep there and back draws two, a turn one (scan/deflector.py)."""
    return 2 if deflector == "oscillating" else 1


def _dense_archetypes(species: tuple[str, ...], crown_ratio: float | None) -> dict:
    """``forest.archetypes`` for the families in :data:`DENSE_SHOOTS`: their templates with denser shoots
    and, where the scan gave one, its conical crowns' ratio (:func:`~.foliage.crown_ratio`)."""
    from ..specs.archetypes import FAMILY_ARCHETYPES
    out = []
    for family in dict.fromkeys(species):
        if family in DENSE_SHOOTS:
            rule = DENSE_SHOOTS[family]
            fixed = {k: v for k, v in rule.items() if k != "branches"}
            out += [{"species": family, "base": k, "branches": int(round(a.branches * rule["branches"])), **fixed,
                     **({"crown_ratio": round(crown_ratio, 3)} if crown_ratio else {})}
                    for k, a in enumerate(FAMILY_ARCHETYPES[family], 1)]
    return {"archetypes": out} if out else {}


def surround_width(tree_heights, field_of_view: float | None) -> float:
    """``forest.surround`` (m) for trees of ``tree_heights`` scanned over ``field_of_view`` (deg, full;
    ``None``: 90): the horizontal run of a pulse at the half field of view (at most :data:`SURROUND_ANGLE`)
    from the tallest tree's top to the ground, within :data:`SURROUND_MAX`; 0 without trees."""
    if not len(tree_heights):
        return 0.0
    angle = min((field_of_view or 90.0) / 2, SURROUND_ANGLE)
    return float(min(round(float(np.max(tree_heights)) * math.tan(math.radians(angle)), 1), SURROUND_MAX))


def _crs_text(wkt: str | None) -> str | None:
    """The file's CRS as short as pyproj can say it (an EPSG code where it has one)."""
    if not wkt:
        return None
    from pyproj import CRS
    crs = CRS.from_wkt(wkt)
    code = crs.to_authority()
    return f"{code[0]}:{code[1]}" if code and CRS.from_user_input(f"{code[0]}:{code[1]}").equals(crs) else wkt


def _write_dem(path: Path, dem: np.ndarray, x0: float, y0: float, crs: str | None) -> None:
    import rasterio
    from rasterio.transform import Affine   # (from_origin warns of its own '*' in rasterio 1.4)
    north_up = dem[::-1].astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=dem.shape[1], height=dem.shape[0], count=1, dtype="float32",
                       transform=Affine(DEM_CELL, 0.0, x0, 0.0, -DEM_CELL, y0 + dem.shape[0] * DEM_CELL),
                       crs=crs, compress="deflate") as dataset:
        dataset.write(north_up, 1)


def _write_trees(path: Path, trees, species: tuple[str, ...], lai: float | None, ratios) -> None:
    """``trees.csv``; with a crown LAI, each tree's leaf area is it times the tree's crown area; with crown
    ratios (k,), each tree's own (:func:`~.foliage.tree_crown_ratios`; a nan leaves the template's)."""
    ratios = np.asarray(ratios, float) if ratios is not None else np.full(len(trees.x), np.nan)
    with_ratio = bool(np.isfinite(ratios).any())
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["x", "y", "height", "crown_radius", "species"] + (["leaf_area"] if lai is not None else [])
                     + (["crown_ratio"] if with_ratio else []))
        for i in range(len(trees.x)):
            leaf = [f"{lai * np.pi * trees.crown_radius[i] ** 2:.2f}"] if lai is not None else []
            ratio = ([f"{ratios[i]:.3f}" if np.isfinite(ratios[i]) else ""] if with_ratio else [])
            out.writerow([f"{trees.x[i]:.3f}", f"{trees.y[i]:.3f}", f"{trees.height[i]:.3f}",
                          f"{trees.crown_radius[i]:.3f}", species[i % len(species)]] + leaf + ratio)


def _bushes_that_fit(called_for: int, size, log) -> int:
    """The scan's bush count, or as many as the plot places for sure (a narrow clip none), said on ``log``.
    Each bush keeps a clear disc 3.4 m across, so a plot thick with shrubs calls for more than fit."""
    fit = min(called_for, int(BUSH_SHARE * understory_capacity(size, "bush")))
    if fit < called_for:
        log(f"twin: understory.bushes: {called_for} called for, {fit} fit in a {size[0]:g} x {size[1]:g} m plot; "
            f"using {fit}")
    return fit


def write_twin(analysis: dict, scan, out: Path, name: str, species: tuple[str, ...], sensor, log) -> dict:
    """Write the scene folder (see the module docstring) and return the report."""
    from ..config import load_scene
    from ..write import check_output_folder
    log = log or (lambda msg: print(msg, file=sys.stderr))
    species = species or (DEFAULT_SPECIES,)
    check_output_folder(out)
    frame, trees = analysis["frame"], analysis["trees"]
    survey, sensor_value, survey_report = survey_plan(analysis, sensor)
    bushes = _bushes_that_fit(analysis["bushes"], frame.size, log)
    crs = _crs_text(scan.crs)
    scene = {
        "name": name, "seed": 0, "area": {"size": list(frame.size)},
        "origin": {"offset": list(frame.offset), **({"crs": crs} if crs else {})},
        "terrain": {"type": "dem", "path": f"{name}_dem.tif"},
        "forest": {"trees_file": "trees.csv", "tilt": 3.0,
                   "surround": surround_width(trees.height, analysis["survey"].field_of_view),
                   **_dense_archetypes(species, analysis.get("crown_ratio"))},
        "understory": {"bushes": bushes, "rocks": 0, "deadwood": 0, "stumps": 0},
        "sensor": sensor_value, "survey": survey,
        "output": {"formats": ["laz"]},
    }
    report = {
        "name": name, "source": str(Path(scan.path).resolve()), "points": len(scan), "crs": crs,
        "plot": {"offset": list(frame.offset), "size": list(frame.size)},
        "ground": analysis["ground_source"],
        "trees": {"count": len(trees.x), "method": "variable-window local maxima (Popescu & Wynne 2004) on a CHM, "
                  "crowns by marker watershed (priority flood)", "settings": dataclasses.asdict(analysis["settings"]),
                  "species": list(species), "crown_gap_fraction": analysis["crown_gap_fraction"],
                  "median_scan_angle": analysis["scan_angle"], "crown_lai": analysis["crown_lai"],
                  "crown_ratio": analysis.get("crown_ratio"),
                  "own_crown_ratios": _own_ratios(analysis.get("tree_crown_ratios"), analysis.get("crown_ratio")),
                  "leaf_area": "crown LAI (Beer-Lambert, G = 0.5) x crown area" if analysis["crown_lai"] is not None
                  else "the species template's, in proportion to crown volume"},
        "understory": {"bushes": bushes, "bushes_called_for": analysis["bushes"],
                       "shrub_area_m2": analysis["shrub_area_m2"],
                       "note": "bush count from the area of 1 m cells rich in returns 0.5-3 m above ground; "
                               "placed at random (the scene format has no bush positions)"},
        "survey": survey_report, "notes": analysis["notes"],
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.twin.", dir=out.parent))
    try:
        x0, y0 = analysis["dem_origin"]
        _write_dem(staging / f"{name}_dem.tif", analysis["dem"], x0, y0, crs)
        _write_trees(staging / "trees.csv", trees, species, analysis["crown_lai"], analysis.get("tree_crown_ratios"))
        (staging / f"{name}.yaml").write_text(f"# A twin of {Path(scan.path).name} written by mitsuforest twin; "
                                              "see twin.json for what was estimated.\n"
                                              + yaml.safe_dump(scene, sort_keys=False, width=120))
        (staging / "twin.json").write_text(json.dumps(report, indent=1, default=_plain) + "\n")
        load_scene(staging / f"{name}.yaml")          # the scene must load as it is
        out.mkdir(parents=True, exist_ok=True)
        for f in staging.iterdir():
            f.replace(out / f.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    for key, item in survey_report.items():
        if not str(item["source"]).startswith("estimated"):
            log(f"twin: survey.{key}: {item['source']}; using {_shown(item['value'])}")
    for note in analysis["notes"]:
        log(f"twin: {note}")
    return report


def _own_ratios(ratios, stand) -> int:
    """How many trees have a crown ratio of their own (not the stand's; :func:`~.foliage.tree_crown_ratios`)."""
    if ratios is None:
        return 0
    ratios = np.asarray(ratios, float)
    return int(np.count_nonzero(np.isfinite(ratios) & (ratios != stand)))


def _shown(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _plain(x):
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(type(x))
