"""Stage 1: a scene file becomes a deterministic placement plan.

>>> plan = plan_scene(load_scene("scenes/demo.yaml"), tree_shapes)   # doctest: +SKIP

(:func:`mitsuforest.survey.make_plan` passes :func:`mitsuforest.trees.tree_shapes`.)

The plan is plain JSON-ready data: the models to build, every placed object with its transform and
ids, the measured canopy cover and the flight legs. The same scene and seed give the same plan,
byte for byte, when written with :func:`plan_json`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from .. import seeds
from ..classes import DEADWOOD_TREEID, GROUND_OBJECT_ID
from ..config import MAX_LEGS, MAX_STEMS_PER_M2, most_stems, scene_error
from ..errors import UserError, amount
from ..specs.understory import CLEARANCE, SHRUB_FORMS, UNDERSTORY_COMPONENTS, UNDERSTORY_KEYS
from ..specs.archetypes import Archetype, UniqueTrees, grown_to, nearest_template, unique_archetypes
from ..specs.sources import MAX_HEIGHT, MeshTree, QsmTree
from .cover import CoverGrid, PlacedOutlines, crown_outline
from .flight import flight_legs
from .ground_layer import place_ground_layer, slope_tilts
from .terrain import Terrain, make_terrain
from .transforms import apply
from .tree_list import read_tree_list
from .types import Leg, ModelSpec, PlacedObject, Plan

__all__ = ["plan_scene", "TreeShapes", "plan_json", "Plan", "PlacedObject", "ModelSpec", "Leg", "Terrain", "UNDERSTORY_MODELS"]

BUSH_MODELS = 8          # bushes are instances of this many distinct shrubs
MAX_TREES = 5000
MAX_TREE_MODELS = 65_534   # treeid is 16 bits, and deadwood takes the number after the last tree model
UNDERSTORY_MODELS = tuple(UNDERSTORY_KEYS)


class _Refusal(Exception):
    """A scene the plan cannot be made of: raised as the scene file's ConfigError by plan_scene."""

    def __init__(self, key: str, reason: str):
        super().__init__(reason)
        self.key, self.reason = key, reason


TreeShapes = Callable[..., list[tuple[np.ndarray, int]]]
"""``tree_shapes(sources, keep=True)``: of each tree model in ``sources``, its (k, 3) crown points, model frame,
and its labelled component count; ``keep`` false (one for all, or one per source) for a plot's drawn unique
trees, whose shapes are not worth keeping (see :func:`mitsuforest.trees.tree_shapes`, the trees stage's
answer, which the plan cannot import). One call takes many, so that the trees stage may grow them at once."""


def plan_scene(scene, tree_shapes: TreeShapes) -> Plan:
    """Place trees and understory, measure canopy cover, lay out the flight legs of a
    :class:`~mitsuforest.config.types.Scene`.

    :param tree_shapes: the crown points and component count of tree models, for spacing, canopy cover and
        object ids: the plan's one call into the trees stage, passed in by its caller.
    :raises ConfigError: ``FILE: key.path: reason`` when the scene cannot be planned.
    """
    try:
        return _plan(scene, tree_shapes)
    except _Refusal as r:
        raise scene_error(scene, r.key, r.reason) from None


def _plan(scene, tree_shapes: TreeShapes) -> Plan:
    rng = seeds.rng(scene.seed, "trees")
    size = scene.area.size
    try:
        terrain = make_terrain(scene.terrain, size, scene.seed, origin=scene.origin)
    except UserError as e:
        raise _Refusal("terrain.path", str(e)) from None
    legs = _checked_legs(scene, flight_legs(size, scene.survey, terrain.mean_height), terrain)   # before the slow part
    listed = _tree_list(scene) if scene.forest.trees_file else None
    tree_models = _tree_models(scene.forest, scene.seed, tree_shapes) if listed is None else \
        _listed_tree_models(scene, listed, tree_shapes)
    crowns = [crown for crown, _ in tree_models.values()]
    models = {name: spec for name, (_, spec) in tree_models.items()}
    if listed is None:
        trees, cover = _place_trees(scene.forest, size, crowns, terrain, rng)
    else:
        trees, cover = _place_listed_trees(listed, size, crowns, terrain, scene.forest.tilt, rng)
    understory, understory_models = _place_understory(scene, size, trees, terrain,
                                                      seeds.rng(scene.seed, "understory"),
                                                      deadwood_treeid=_deadwood_treeid(len(models)))
    models.update(understory_models)
    ground_layer, ground_layer_models = place_ground_layer(scene.understory, size, terrain, scene.seed)
    models.update(ground_layer_models)
    around = _surrounding_copies(trees, size, scene.forest.surround, terrain) if listed is not None else []
    return Plan(
        scene=scene.name, seed=scene.seed, area=tuple(size), forest_type=scene.forest.type,
        canopy_cover=round(cover, 6), terrain=terrain, models=models,
        objects=tuple(_with_ids(trees + understory + ground_layer + around, models)),
        legs=tuple(legs),
    )


MAX_LEG_PULSES = 2 ** 32     # time slots are numbered in 32 bits within a leg
TALLEST = MAX_HEIGHT         # m: the tallest object a scene may hold (an imported tree), which a leg out of the
                             # ground's range may still reach


def _checked_legs(scene, legs: list[Leg], terrain: Terrain) -> list[Leg]:
    """Refuse legs that overflow the per-leg pulse counter, never come within reach of the plot, or fly
    into the ground, and more legs than a point's 16-bit ``point_source_id`` can number."""
    _check_ground_below_flight(scene, legs, terrain)
    if len(legs) > MAX_LEGS:
        raise _Refusal("survey.trajectory" if scene.survey.trajectory else "survey",
                       f"{len(legs):,} flight lines, more than the {MAX_LEGS:,} that LAS point_source_id can number")
    top, pulses = float(terrain.z.max()), 0
    for i, leg in enumerate(legs):
        key = f"survey.lines[{i}]" if scene.survey.lines else "survey.trajectory" if leg.track else "survey"
        seconds = leg.t1 - leg.t0
        if not seconds * scene.pulse_frequency < MAX_LEG_PULSES:   # inf and nan too: legs of 1e300 m
            raise _Refusal("survey.trajectory" if leg.track is not None else "survey.speed",   # the file's times
                           f"leg {i + 1} lasts {amount(seconds)} s: "
                           f"{amount(seconds * scene.pulse_frequency)} pulses, more than the {MAX_LEG_PULSES:,} a leg "
                           "can number; fly faster or split the leg")
        pulses += leg.pulse_count(scene.pulse_frequency)
        gap, reach = _leg_gap(leg, scene.area.size), _reach(scene, leg, terrain)
        if gap > reach:
            raise _Refusal(key, f"the leg passes {amount(gap, 1)} m from the plot, beyond the sensor's reach of "
                           f"{reach:,.1f} m at this altitude")
        nearest = math.hypot(gap, max(0.0, float(leg.positions()[:, 2].min()) - top - TALLEST))
        if nearest > scene.sensor.range_max:
            where = "survey.altitude" if key == "survey" or (gap == 0 and not leg.track) else key
            raise _Refusal(where, f"the plot's ground, and anything {TALLEST:g} m tall on it, lies "
                           f"{amount(nearest, 1)} m from leg {i + 1} at the nearest, beyond the sensor's range_max "
                           f"of {scene.sensor.range_max:,g} m: no pulse would reach it")
    if legs and not pulses:
        raise _Refusal("survey", f"fires no pulse: {len(legs)} leg(s) of {amount(legs[-1].t1 - legs[0].t0, 3)} s "
                       f"at {scene.pulse_frequency:g} Hz; fly slower or give a higher pulse frequency")
    return legs


def _check_ground_below_flight(scene, legs: list[Leg], terrain: Terrain) -> None:
    """The plot's highest ground must lie at least the sensor's minimum range below the lowest leg: higher
    ground would put the platform in or under the terrain (points above it, pulses fired upwards)."""
    top, flight = float(terrain.z.max()), min(min(leg.start[2], leg.end[2]) for leg in legs)
    clearance = scene.sensor.range_min
    if top > flight - clearance:
        if scene.survey.trajectory:   # survey.altitude is not flown: the file's heights are
            plus = f" plus the sensor's minimum range {clearance:g} m" if clearance else ""
            raise _Refusal("survey.trajectory", f"the trajectory comes down to z {flight:,.1f} m, below the ground's "
                           f"highest point at {top:,.1f} m{plus}; its heights must be in the scene's local frame "
                           "(origin.offset subtracted)")
        if scene.survey.altitude < clearance:      # flat ground too: the flight itself is too low
            raise _Refusal("survey.altitude", f"{scene.survey.altitude:g} m is under the sensor's minimum range "
                           f"{clearance:g} m ({scene.sensor.name}): it would see nothing; fly at least that high")
        key = "terrain.amplitude" if scene.terrain.type == "noise" else "survey.altitude"
        less = f" less the sensor's minimum range {clearance:g} m" if clearance else ""
        raise _Refusal(key, f"the ground rises {top - terrain.mean_height:,.1f} m above its mean height, higher than "
                       f"the flight at survey.altitude {scene.survey.altitude:g} m{less}; fly higher or give gentler "
                       "terrain")


def _leg_gap(leg: Leg, size) -> float:
    """Horizontal distance (m) between a leg and the plot rectangle (0 when it crosses the plot)."""
    if leg.track is not None:
        along = leg.track.position[:, :2]
    else:
        a, b = np.array(leg.start[:2]), np.array(leg.end[:2])
        along = np.linspace(0.0, 1.0, 1001)[:, None] * (b - a) + a
    outside = np.maximum(np.maximum(-along, along - np.asarray(size)), 0.0)
    return float(np.hypot(outside[:, 0], outside[:, 1]).min())


def _reach(scene, leg: Leg, terrain: Terrain) -> float:
    """How far from the track (m) a pulse's beam axis of ``leg`` can reach the ground, down to the terrain's
    lowest point in the plot (the terrain's own heights: a DEM's or a mesh's range, not ``terrain.amplitude``),
    with the swath the platform's attitude and the sensor's mount lean (:func:`~.reach.leg_swaths`)."""
    from .reach import leg_swaths
    swath = leg_swaths([leg], scene.sensor, scene.survey.attitude, beam=False)[0]
    return float(swath.reach(swath.top - float(terrain.z.min()), scene.sensor.range_max)) + swath.margin


def plan_json(plan: Plan) -> str:
    """The plan as canonical JSON text (stable key order and float formatting)."""
    return plan.to_json()


def _deadwood_treeid(tree_models: int) -> int:
    """Deadwood's treeid: 11, or one past the last tree model when there are more than ten."""
    return max(DEADWOOD_TREEID, tree_models + 1)


def _tree_models(forest, seed: int, tree_shapes: TreeShapes) -> dict[str, tuple[np.ndarray, ModelSpec]]:
    """``treeNN``: (crown points, spec) of the archetypes (a unique entry's N drawn trees in its place),
    then of the imported models (``forest.models``), numbered on: tree model N carries treeid N."""
    archetypes, drawn = [], []
    for i, entry in enumerate(forest.archetypes):
        unique = isinstance(entry, UniqueTrees)
        for a in unique_archetypes(entry, seed, i) if unique else (entry,):
            archetypes.append(a)
            drawn.append(unique)
    crowns, specs = [], []
    for a, d, (crown, components) in zip(archetypes, drawn, tree_shapes(archetypes, keep=[not d for d in drawn])):
        crowns.append(crown)
        specs.append(ModelSpec("tree", components, archetype=a, drawn=d or None))
    for entry, (crown, components) in zip(forest.models, tree_shapes(forest.models)):  # builds (or loads) the models
        crowns.append(crown)
        specs.append(ModelSpec("tree", components, source=entry))
    return {f"tree{i + 1:02d}": (crown, spec) for i, (crown, spec) in enumerate(zip(crowns, specs))}


def _tree_list(scene) -> list:
    """The rows of ``forest.trees_file`` in the local frame; none may stand outside the plot."""
    try:
        listed = read_tree_list(scene.forest.trees_file, scene.origin.offset)
    except UserError as e:
        raise _Refusal("forest.trees_file", str(e)) from None
    if len(listed) > MAX_TREE_MODELS:
        raise _Refusal("forest.trees_file", f"{len(listed):,} trees, at most {MAX_TREE_MODELS:,} (treeid is 16 bits)")
    w, h = scene.area.size
    if len(listed) > (most := most_stems(scene.area.size)):   # as forest.trees: each row builds a crown
        raise _Refusal("forest.trees_file", f"{len(listed):,} trees in a {w:g} x {h:g} m plot is more than "
                       f"{MAX_STEMS_PER_M2:g} a square metre (at most {most:,}; the densest young stands hold about 10)")
    for i, t in enumerate(listed):
        if not (0 <= t.x <= w and 0 <= t.y <= h):
            raise _Refusal("forest.trees_file", f"tree {i + 1} stands at local x {t.x:.2f}, y {t.y:.2f}, outside the "
                           f"plot 0..{w:g} x 0..{h:g} m (origin.offset subtracted)")
    return listed


def _listed_tree_models(scene, listed, tree_shapes: TreeShapes) -> dict[str, tuple[np.ndarray, ModelSpec]]:
    """One procedural model per listed tree: the scene's (or its family's) archetype of the tree's species
    nearest in height, grown to the tree's height and crown (:func:`~mitsuforest.specs.archetypes.grown_to`)."""
    archetypes = scene.forest.archetypes
    default_species = archetypes[0].species if archetypes else "eucalyptus"
    grown = [grown_to(nearest_template(t.species or default_species, t.height, archetypes), t.height,
                      2 * t.crown_radius, seed=seeds.key(scene.seed, "listed-tree", i, bits=31),
                      leaf_area=t.leaf_area, crown_ratio=t.crown_ratio)
             for i, t in enumerate(listed)]
    return {f"tree{i + 1:02d}": (crown, ModelSpec("tree", components, archetype=a))
            for i, (a, (crown, components)) in enumerate(zip(grown, tree_shapes(grown)))}


def _place_listed_trees(listed, size, crowns, terrain, tilt_max, rng) -> tuple[list[PlacedObject], float]:
    """Each listed tree where the list puts it, model N for row N; the canopy cover they make."""
    grid, trees = CoverGrid(size), []
    for k, t in enumerate(listed):
        tree = _tree(k, (t.x, t.y), terrain, tilt_max, rng)
        grid.add(crown_outline(apply(tree.matrix, crowns[k])))
        trees.append(tree)
    return trees, grid.fraction


def _surrounding_copies(trees: list[PlacedObject], size, width: float, terrain) -> list[PlacedObject]:
    """``forest.surround``: the listed trees repeated with the plot's period (shifted by whole plot widths
    and depths) wherever a copy stands outside the plot within ``width`` m of it, each on the ground at
    its place (the terrain's edge height beyond it) with its original's model, rotation and tilt. A plot
    cut from a forest is seen through the stand around it: pulses at 45-70 degrees reach its ground from
    beyond its edges, and without a stand there they pass under the crowns (README, "Twins of real plots")."""
    if width <= 0:
        return []
    w, h = size
    out = []
    for i in range(-math.ceil(width / w), math.ceil(width / w) + 1):
        for j in range(-math.ceil(width / h), math.ceil(width / h) + 1):
            for t in trees if (i, j) != (0, 0) else ():
                x, y = t.position[0] + i * w, t.position[1] + j * h
                if -width <= x <= w + width and -width <= y <= h + width:
                    out.append(dataclasses.replace(t, position=(x, y, float(terrain.height(x, y)) - 0.05)))
    return out


def _tree(archetype_index: int, xy, terrain, tilt_max, rng) -> PlacedObject:
    return PlacedObject(
        kind="tree", model=f"tree{archetype_index + 1:02d}", treeid=archetype_index + 1,
        position=(float(xy[0]), float(xy[1]), float(terrain.height(xy[0], xy[1])) - 0.05),
        rotation=float(rng.uniform(0, 360)),
        tilt=(float(rng.uniform(-tilt_max, tilt_max)), float(rng.uniform(-tilt_max, tilt_max))),
    )


def _place_trees(forest, size, crowns, terrain, rng) -> tuple[list[PlacedObject], float]:
    """Dart throwing with ``min_spacing`` until the tree count or the canopy-cover target is met.

    Each tree draws an entry of ``forest.archetypes`` and ``forest.models`` by weight; a unique entry
    then gives its next drawn tree in turn, so its N trees are all placed before any is placed twice."""
    entries = (*forest.archetypes, *forest.models)
    weights = np.array([a.weight for a in entries], float)
    weights /= weights.sum()
    sizes = [e.unique if isinstance(e, UniqueTrees) else 1 for e in entries]
    first, placed = np.cumsum([0, *sizes[:-1]]), [0] * len(entries)
    target_count, target_cover = forest.trees, forest.target_cover
    grid, outlines = CoverGrid(size), PlacedOutlines(crowns)
    trees = []
    spacing = forest.min_spacing
    stems = _Stems(spacing + 1.0)     # a metre more than the spacing, beyond any rounding of the cells
    misses = 0
    while True:
        if target_count is not None and len(trees) >= target_count:
            break
        if target_count is None and (grid.fraction >= target_cover or len(trees) >= MAX_TREES):
            break
        xy = rng.uniform([0, 0], size)
        if stems.nearest(xy) < spacing:
            misses += 1
            if misses > 20_000:
                raise _Refusal("forest.min_spacing", f"cannot place tree {len(trees) + 1} at {spacing:g} m from "
                               f"the others in a {size[0]:g} x {size[1]:g} m plot; lower it or the tree target")
            continue
        misses = 0
        e = int(rng.choice(len(weights), p=weights))
        k = int(first[e]) + placed[e] % sizes[e]
        placed[e] += 1
        tree = _tree(k, xy, terrain, forest.tilt, rng)
        grid.add(outlines.outline(k, tree.matrix))
        trees.append(tree)
        stems.add(xy)
    if target_count is None and grid.fraction < target_cover:
        raise _Refusal("forest.canopy_cover", f"reached only {grid.fraction:.3f} of {target_cover:g} "
                       f"with {len(trees)} trees; lower it or forest.min_spacing")
    return trees, grid.fraction


class _Stems:
    """The trees placed so far, filed by square cells of side ``cell``: any stem nearer than ``cell`` to
    a place lies in its cell or the eight around it, so the nearest within that distance is found among
    those (comparing with every stem made placing a 100 ha plot's 12,100 trees take 6 s)."""

    def __init__(self, cell: float):
        self.cell = cell
        self._cells: dict[tuple[int, int], list[np.ndarray]] = {}

    def _key(self, xy) -> tuple[int, int]:
        return math.floor(xy[0] / self.cell), math.floor(xy[1] / self.cell)

    def add(self, xy: np.ndarray) -> None:
        self._cells.setdefault(self._key(xy), []).append(xy)

    def nearest(self, xy: np.ndarray) -> float:
        """The distance from ``xy`` (2,) to the nearest stem if it is less than ``cell``, else at least ``cell``
        (infinity when none is near)."""
        i, j = self._key(xy)
        near = [p for a in (i - 1, i, i + 1) for b in (j - 1, j, j + 1) for p in self._cells.get((a, b), ())]
        return float(np.min(np.hypot(*(np.array(near) - xy).T))) if near else math.inf


# Half-widths (m) kept clear around each kind's axis: the largest model of the kind (understory.py)
# plus a margin. Stems keep 0.6 m (flared base, and 5° tilt over the first 3 m).
STEM_CLEARANCE = 0.6
MIN_LOG = 1.5  # m, the shortest log drawn
OCCUPIED_CELL = 4.0  # m, the cells by which placed footprints are looked up


def _place_understory(scene: dict, size, trees, terrain, rng, deadwood_treeid: int = DEADWOOD_TREEID):
    """Bushes, rocks, deadwood and stumps at random, clear of stems and of each other, each wholly
    inside the plot (the ground ends at the plot's edge: a part beyond it would show its buried base).

    Each object occupies a corridor of half-width CLEARANCE around its axis (a point, or a log's
    length); a new object is placed only where its corridor meets no other and stays in the plot.
    """
    counts = scene.understory_counts
    taken = _Occupied([_Footprint(np.array(t.position[:2]), 0.0, 0.0, STEM_CLEARANCE) for t in trees])
    objects, models = [], {}
    for i in range(BUSH_MODELS if counts["bushes"] else 0):   # every shrub form, in turn
        models[f"bush{i + 1:02d}"] = ModelSpec("bush", UNDERSTORY_COMPONENTS,
                                               seed=seeds.key(scene.seed, "bush-model", i, bits=31),
                                               form=i % len(SHRUB_FORMS))
    for kind, key in UNDERSTORY_KEYS.items():
        for i in range(counts[key]):
            spec = ModelSpec(kind, UNDERSTORY_COMPONENTS, seed=int(rng.integers(0, 2**31 - 1)))
            if kind == "deadwood":
                spec = dataclasses.replace(spec, length=float(rng.uniform(MIN_LOG, 7.0)),
                                           radius=float(rng.uniform(0.04, 0.2)))
            spot = _free_spot(size, taken, spec.length or 0.0, CLEARANCE[kind], rng, kind)
            if spec.length:
                spec = dataclasses.replace(spec, length=spot.length)
            if kind == "bush":
                model = f"bush{int(rng.integers(0, BUSH_MODELS)) + 1:02d}"
            else:
                model = f"{kind}{i + 1:03d}"
                models[model] = spec
            taken.add(spot)
            x, y = spot.centre
            tilt = _lying_tilt(terrain, spot.centre, spot.yaw, spot.length) if kind == "deadwood" else (0.0, 0.0)
            objects.append(PlacedObject(
                kind=kind, model=model, treeid=deadwood_treeid if kind == "deadwood" else 0,
                position=(float(x), float(y), float(terrain.height(x, y))), rotation=spot.yaw, tilt=tilt))
    return objects, models


def _lying_tilt(terrain, centre, yaw: float, length: float) -> tuple[float, float]:
    """Tilts (degrees) that lay a log of ``length`` at ``centre``, along ``yaw`` (degrees from +x), on the
    plane fitted to the terrain's heights along it and 0.5 m to either side, so it lies along a slope
    rather than level at its centre's height; (0, 0) on level ground."""
    along, across = np.meshgrid(np.linspace(-length / 2, length / 2, 9), [-0.5, 0.0, 0.5])
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    dx, dy = (along * c - across * s).ravel(), (along * s + across * c).ravel()
    heights = terrain.height(centre[0] + dx, centre[1] + dy)
    _, p, q = np.linalg.lstsq(np.column_stack([np.ones_like(dx), dx, dy]), heights, rcond=None)[0]
    tilt_x, tilt_y = slope_tilts(np.array([p]), np.array([q]))
    return float(tilt_x[0]) + 0.0, float(tilt_y[0]) + 0.0        # + 0.0: no -0.0 in the plan's JSON


class _Footprint:
    """A segment of ``length`` through ``centre`` at ``yaw`` (degrees), widened by ``clearance``: its axis
    ``samples`` (k, 2), and ``low`` and ``high``, the corners [x, y] of the box around them."""

    def __init__(self, centre, yaw: float, length: float, clearance: float):
        self.centre, self.yaw, self.length, self.clearance = centre, float(yaw), float(length), clearance
        if length:
            direction = np.array([np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))])
            steps = np.linspace(-0.5, 0.5, max(int(np.ceil(length / 0.2)), 0) + 1)
            self.samples = centre + steps[:, None] * length * direction  # axis points 0.2 m apart at most
            self.low, self.high = self.samples.min(axis=0).tolist(), self.samples.max(axis=0).tolist()
        else:
            self.samples = np.array([centre], float)
            self.low = self.high = self.samples[0].tolist()

    def inside(self, low, high) -> bool:
        """Whether the axis lies within the box ``low``-``high``, shape (2,) each."""
        return low[0] <= self.low[0] and low[1] <= self.low[1] and self.high[0] <= high[0] and self.high[1] <= high[1]

    def cells(self, reach: float) -> tuple[range, range]:
        """The OCCUPIED_CELL cells, by x and by y, of the box around the axis widened by ``reach``."""
        (x0, y0), (x1, y1) = self.low, self.high
        return (range(math.floor((x0 - reach) / OCCUPIED_CELL), math.floor((x1 + reach) / OCCUPIED_CELL) + 1),
                range(math.floor((y0 - reach) / OCCUPIED_CELL), math.floor((y1 + reach) / OCCUPIED_CELL) + 1))


class _Occupied:
    """The footprints placed so far, their axis samples filed by square cells of OCCUPIED_CELL metres,
    so that a candidate is tested against those near it only (against all of them, a 9 ha plot's 2,500
    understory objects took 12 s to place)."""

    def __init__(self, footprints=()):
        self._cells: dict[tuple[int, int], list[tuple[float, float, float]]] = {}   # cell -> (x, y, clearance)
        self._widest = 0.0
        for footprint in footprints:
            self.add(footprint)

    def add(self, footprint: _Footprint) -> None:
        for x, y in footprint.samples.tolist():
            cell = (math.floor(x / OCCUPIED_CELL), math.floor(y / OCCUPIED_CELL))
            self._cells.setdefault(cell, []).append((x, y, footprint.clearance))
        self._widest = max(self._widest, footprint.clearance)

    def admit(self, footprint: _Footprint) -> bool:
        """Whether ``footprint`` keeps the sum of the two clearances from every placed footprint.

        Only the samples in cells within the largest such sum (and a metre more, beyond any rounding)
        are compared: every other lies farther away on x or y alone, so the answer is that of
        comparing all of them."""
        xs, ys = footprint.cells(footprint.clearance + self._widest + 1.0)
        near = [sample for x in xs for y in ys for sample in self._cells.get((x, y), ())]
        if not near:
            return True
        if len(footprint.samples) == 1:     # a point: in Python, the same arithmetic as numpy's below
            (x, y), c = footprint.low, footprint.clearance
            return all((x - px) * (x - px) + (y - py) * (y - py) >= (c + pc) * (c + pc) for px, py, pc in near)
        placed = np.array(near)
        d = footprint.samples[:, None, :] - placed[None, :, :2]
        gap = footprint.clearance + placed[:, 2]
        return bool(np.all(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] >= gap * gap))


def _free_spot(size, taken: _Occupied, length, clearance, rng, kind) -> _Footprint:
    """A random place for an object clear of ``taken``; a log that finds none is shortened by steps
    (down to MIN_LOG, as a crowded or small plot needs) rather than refused."""
    low, high = np.full(2, clearance), np.asarray(size, float) - clearance
    tries, drawn = 10_000, length
    for i in range(tries):
        if drawn > MIN_LOG:
            length = MIN_LOG + (1 - i / tries) * (drawn - MIN_LOG)
        spot = _Footprint(rng.uniform(low, high), rng.uniform(0, 360), length, clearance)
        if spot.inside(low, high) and taken.admit(spot):
            return spot
    raise _Refusal(f"understory.{UNDERSTORY_KEYS[kind]}", f"no free place left for another {kind}; lower the understory counts")


def _with_ids(objects: list[PlacedObject], models: dict[str, ModelSpec]) -> list[PlacedObject]:
    """Instance ids 1.. per object; object ids per component, counting on from the ground's."""
    out, next_object_id = [], GROUND_OBJECT_ID + 1
    for instance, obj in enumerate(objects, start=1):
        components = models[obj.model].components
        out.append(dataclasses.replace(obj, instance=instance, object_id=next_object_id, components=components))
        next_object_id += components
    return out
