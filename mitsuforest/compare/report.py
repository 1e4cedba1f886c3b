"""Two point clouds side by side: each one's description, the distances between them, the table."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import metrics as m
from .cloud import Cloud, as_cloud, like_for_like, load_cloud, within_footprint

RETURN_NUMBERS = (1, 2, 3)   # intensity by return number; intensity_ks is the largest KS of these
MIN_ECHOES = 20              # a return number with fewer echoes in either cloud is left out of intensity_ks
DISTANCE_KEYS = ("returns_tv", "height_ks", "height_emd_m", "canopy_p95_m", "ground_share", "intensity_ks",
                 "density_ratio")


@dataclass
class Description:
    """A cloud's summary (the ``a`` or ``b`` of compare.json) and the arrays behind its distances."""

    cloud: Cloud
    summary: dict
    height: np.ndarray                     # (n,) every point's height above the ground (m)
    pulses: np.ndarray                     # (k,) pulses by number of returns
    intensity: np.ndarray | None           # (n,) intensity / the first-return ground median


def describe(cloud: Cloud) -> Description:
    """Measure one cloud (see README, "Comparing scans", for each definition)."""
    x, y, z = cloud.x, cloud.y, cloud.z
    notes = list(cloud.notes)
    first = m.first_returns(cloud.return_number)
    last = m.last_returns(cloud.return_number, cloud.number_of_returns)
    area = m.covered_area(x, y)
    pulses = m.pulses_by_returns(cloud.return_number, cloud.number_of_returns)

    ground, source = _ground(cloud, notes)
    model = m.ground_model(x, y, x[ground], y[ground], z[ground])
    if model.cell > m.CELL_M:       # a file this wide has points far apart: say that its ground is coarse
        notes.append(f"the points span {max(np.ptp(x), np.ptp(y)):,.0f} m: the ground model's cells are "
                     f"{model.cell:,.1f} m, not {m.CELL_M:g} m (at most {m.MAX_GRID_CELLS:,} cells), and heights "
                     "follow the ground less closely; clip the file to its plot")
    height = m.heights_above(z, model.height(x, y))
    origin = m.grid_origin(x, y)
    cells, canopy = m.canopy_cells(x[first], y[first], height[first], origin)
    reached = height <= m.GROUND_REACH_M
    edges, profile = m.vertical_profile(height)
    intensity, intensity_summary = _intensity(cloud, first & ground, notes)
    summary = {
        "file": cloud.name,
        "points": len(cloud),
        "classes": cloud.scheme,
        "covered_area_m2": area,
        "density_per_m2": len(cloud) / area,
        "pulse_density_per_m2": int(first.sum()) / area,
        "spacing_m": m.median_spacing(x[first], y[first]),
        "pulses": int(pulses.sum()),
        "pulses_by_returns": {str(k): float(s) for k, s in enumerate(m.shares(pulses)) if k and s},
        "ground": {"from": source, "points": int(ground.sum())},
        "height_m": m.percentiles(height),
        "height_profile": {"bin_m": 1.0, "lowest_m": float(edges[0]), "shares": [float(s) for s in profile]},
        "canopy_height_m": m.canopy_heights(height[first]),
        "canopy_cover_2m": m.canopy_cover(canopy),
        "ground_share": float(ground.mean()),
        "near_ground_share": float(reached.mean()),
        "ground_share_under_canopy": m.ground_under_canopy(x[last], y[last], reached[last], origin, cells, canopy),
        "intensity": intensity_summary,
        "scan_angle_deg": None if cloud.scan_angle is None else {
            **m.percentiles(cloud.scan_angle), "max_abs": float(np.max(np.abs(cloud.scan_angle)))},
        "notes": notes,
    }
    return Description(cloud, summary, height, pulses, intensity)


def _ground(cloud: Cloud, notes: list) -> tuple[np.ndarray, str]:
    """(n,) ground mask and where it came from: the ground class, else the lowest-point filter."""
    scheme = f"class {cloud.ground_code} ({'our' if cloud.scheme == 'mitsuforest' else 'ASPRS'} ground)"
    if cloud.classification is not None:
        ground = cloud.classification == cloud.ground_code
        if ground.sum() >= 3:
            return ground, scheme
    source = (f"lowest-point filter (lowest point per {m.FILTER_CELL_M:g} m cell within {m.FILTER_RISE_M:g} m "
              f"of the lowest of the {m.FILTER_WINDOW}x{m.FILTER_WINDOW} cells around it, points within "
              f"{m.FILTER_BAND_M:g} m of their surface)")
    lacking = "no classes" if cloud.classification is None else f"no ground points ({scheme})"
    notes.append(f"{lacking}: ground from the {source}")
    return m.lowest_point_ground(cloud.x, cloud.y, cloud.z), source


def _intensity(cloud: Cloud, first_ground: np.ndarray, notes: list) -> tuple[np.ndarray | None, dict | None]:
    if cloud.intensity is None:
        return None, None
    reference_from = "first-return ground echoes"
    reference = float(np.median(cloud.intensity[first_ground])) if first_ground.any() else 0.0
    if reference <= 0:
        first = m.first_returns(cloud.return_number)
        reference, reference_from = float(np.median(cloud.intensity[first])), "all first returns"
        notes.append("no first-return ground echo with intensity: intensity normalised by the median of all "
                     "first returns")
    if reference <= 0:
        notes.append("median intensity is 0: intensity left out")
        return None, None
    normalised = m.normalised_intensity(cloud.intensity, reference)
    by_return = {str(r): m.percentiles(normalised[cloud.return_number == r]) for r in RETURN_NUMBERS
                 if np.any(cloud.return_number == r)}
    return normalised, {"reference": reference, "reference_from": reference_from, "by_return": by_return}


def distances(a: Description, b: Description) -> dict:
    """The ``distance`` of compare.json (see README, "Comparing scans")."""
    sa, sb = a.summary, b.summary
    return {
        "returns_tv": m.total_variation(m.shares(a.pulses), m.shares(b.pulses)),
        "height_ks": m.ks_statistic(a.height, b.height),
        "height_emd_m": m.earth_movers(a.height, b.height),
        "canopy_p95_m": sb["canopy_height_m"]["p95"] - sa["canopy_height_m"]["p95"],
        "ground_share": sb["ground_share_under_canopy"] - sa["ground_share_under_canopy"],
        "intensity_ks": _intensity_ks(a, b),
        "density_ratio": sb["density_per_m2"] / sa["density_per_m2"],
    }


def _intensity_ks(a: Description, b: Description) -> float:
    if a.intensity is None or b.intensity is None:
        return float("nan")
    found = []
    for r in RETURN_NUMBERS:
        ia, ib = (d.intensity[d.cloud.return_number == r] for d in (a, b))
        if len(ia) >= MIN_ECHOES and len(ib) >= MIN_ECHOES:
            found.append(m.ks_statistic(ia, ib))
    return max(found) if found else float("nan")


def compare_descriptions(a: Description, b: Description) -> dict:
    from ..write.atomic import finite_or_null
    return finite_or_null({"a": a.summary, "b": b.summary, "distance": distances(a, b)})


def compare_clouds(cloud_a, cloud_b) -> dict:
    """compare.json's dict for two clouds in memory: :class:`~.cloud.Cloud` objects, structured point
    arrays (``render(...).points``, our classes) or paths. Undefined values (a cloud without canopy,
    say) are None."""
    a, b = like_for_like(as_cloud(cloud_a, "A"), as_cloud(cloud_b, "B"))
    return compare_descriptions(describe(a), describe(b))


def compare_files(a, b, out_dir=None, within_a: bool = False) -> dict:
    """Compare the point files ``a`` and ``b`` (PCD, LAS or LAZ); with ``out_dir``, write
    ``compare.json`` and ``compare.png`` there (each atomically). With ``within_a``, ``b`` is measured
    only in the 1 m cells that hold a point of ``a`` (:func:`~.cloud.within_footprint`). Where one file
    holds first returns only, the other is measured on its first returns (:func:`~.cloud.like_for_like`).

    :returns: compare.json's dict ``{"a": {...}, "b": {...}, "distance": {...}}``.
    :raises UserError: a missing, damaged or empty file, or an output folder that cannot be written.
    """
    if out_dir is not None:
        from ..write import check_output_folder
        check_output_folder(out_dir)
    cloud_a, cloud_b = load_cloud(a), load_cloud(b)
    if within_a:
        cloud_b = within_footprint(cloud_b, cloud_a, called=f"A ({cloud_a.name})")
    cloud_a, cloud_b = like_for_like(cloud_a, cloud_b)
    da, db = describe(cloud_a), describe(cloud_b)
    result = compare_descriptions(da, db)
    if out_dir is not None:
        from ..write.atomic import write_json
        from .figure import write_compare_figure
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_compare_figure(out / "compare.png", da, db)    # first: a failing figure leaves no compare.json
        write_json(out / "compare.json", result)
    return result


def _fmt(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_table(result: dict) -> str:
    """compare.json as a table: one row per measure, A, B and the distance where there is one."""
    a, b, d = result["a"], result["b"], result["distance"]

    def pulses(s):
        p = s["pulses_by_returns"]
        four = sum(v for k, v in p.items() if int(k) >= 4)
        return " / ".join(f"{p.get(k, 0) * 100:.1f}" for k in "123") + f" / {four * 100:.1f}"

    def triple(v, keys, spec=".1f"):
        return " / ".join(_fmt(v[k], spec) for k in keys) if v else "-"

    def intensity(s):
        i = s["intensity"]
        return " / ".join(_fmt(i["by_return"].get(r, {}).get("p50"), ".2f") for r in "123") if i else "-"

    def angle(s):
        v = s["scan_angle_deg"]
        return f"{_fmt(v['p5'], '.0f')} .. {_fmt(v['p95'], '.0f')}" if v else "-"

    rows = [
        ("points", f"{a['points']:,}", f"{b['points']:,}", ""),
        ("covered area (m², 1 m cells)", f"{a['covered_area_m2']:,.0f}", f"{b['covered_area_m2']:,.0f}", ""),
        ("density (points/m²)", _fmt(a["density_per_m2"], ".1f"), _fmt(b["density_per_m2"], ".1f"),
         f"density_ratio {_fmt(d['density_ratio'], '.3f')}"),
        ("pulses/m² (first returns)", _fmt(a["pulse_density_per_m2"], ".1f"), _fmt(b["pulse_density_per_m2"], ".1f"),
         ""),
        ("median spacing 2-D, first (m)", _fmt(a["spacing_m"], ".3f"), _fmt(b["spacing_m"], ".3f"), ""),
        ("pulses 1/2/3/4+ returns (%)", pulses(a), pulses(b), f"returns_tv {_fmt(d['returns_tv'], '.3f')}"),
        ("height p5/p50/p95 (m)", triple(a["height_m"], ("p5", "p50", "p95")),
         triple(b["height_m"], ("p5", "p50", "p95")),
         f"height_ks {_fmt(d['height_ks'], '.3f')}, height_emd_m {_fmt(d['height_emd_m'], '.2f')}"),
        ("canopy height p50/p95/p99 (m)", triple(a["canopy_height_m"], ("p50", "p95", "p99")),
         triple(b["canopy_height_m"], ("p50", "p95", "p99")), f"canopy_p95_m {_fmt(d['canopy_p95_m'], '+.2f')}"),
        ("canopy cover at 2 m", _fmt(a["canopy_cover_2m"], ".1%"), _fmt(b["canopy_cover_2m"], ".1%"), ""),
        ("ground share (all points)", _fmt(a["ground_share"], ".1%"), _fmt(b["ground_share"], ".1%"), ""),
        (f"within {m.GROUND_REACH_M:g} m of the ground", _fmt(a["near_ground_share"], ".1%"),
         _fmt(b["near_ground_share"], ".1%"), ""),
        (f"last returns ≤ {m.GROUND_REACH_M:g} m under canopy", _fmt(a["ground_share_under_canopy"], ".1%"),
         _fmt(b["ground_share_under_canopy"], ".1%"), f"ground_share {_fmt(d['ground_share'], '+.3f')}"),
        ("intensity / ground median, r1/r2/r3", intensity(a), intensity(b),
         f"intensity_ks {_fmt(d['intensity_ks'], '.3f')}"),
        ("scan angle p5 .. p95 (°)", angle(a), angle(b), ""),
        ("ground from", _ground_word(a), _ground_word(b), ""),
    ]
    header = ("", f"A: {a['file']}", f"B: {b['file']}", "distance (B vs A)")
    widths = [max(len(r[k]) for r in (header, *rows)) for k in range(4)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in (header, *rows)]
    return "\n".join(lines)


def _ground_word(s: dict) -> str:
    source = s["ground"]["from"]
    return source if source.startswith("class") else "lowest-point filter"
