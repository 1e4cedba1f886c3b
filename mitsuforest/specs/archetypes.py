"""Parameters of the procedural trees, the ten default Eucalyptus archetypes and the archetypes of
the other species families (Acacia, Pinus radiata).

Lengths are metres, angles degrees, areas square metres. The generator (:mod:`.skeleton`) reads
nothing but these fields, so an archetype is fully described by them; its hash keys the disk cache.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .. import seeds
from ..classes import TREE_SPECIES


def _p(default, meaning, lo=None, hi=None, integer=False, choices=None):
    return field(default=default, metadata={"meaning": meaning, "lo": lo, "hi": hi, "integer": integer,
                                            "choices": choices})


@dataclass(frozen=True)
class Archetype:
    """One procedural tree (Weber & Penn-style recursive branching) of a species family.

    ``species`` picks the family's crown shape and branching (:mod:`.skeleton`): ``eucalyptus``
    (forking leaders, a half-ellipse crown), ``acacia`` (a low fork into several leaders, a broad
    rounded crown) or ``pinus_radiata`` (one straight leader, branches in whorls, a conical crown).
    """

    height: float = _p(20.0, "total tree height (m)", 2.0, 80.0)
    dbh: float = _p(0.30, "stem diameter at breast height, 1.3 m (m)", 0.02, 3.0)
    taper: float = _p(0.9, "stem form exponent: r(z) ~ (1 - z/H)^taper (1 cone, 0.5 paraboloid)", 0.2, 2.0)
    crown_ratio: float = _p(0.45, "live crown length / height (crown starts at (1 - ratio) * height)", 0.1, 0.95)
    crown_diameter: float = _p(9.0, "target crown width (m)", 0.5, 40.0)
    crown_exponent: float = _p(0.9, "Pinus radiata's crown: radius ~ (depth below the top / crown length)^exponent "
                                    "(1 a cone, 0.5 a paraboloid: blunter)", 0.3, 1.5)
    fork_height: float = _p(0.65, "relative height of the fork into co-dominant leaders (0 = none)", 0.0, 0.95)
    forks: int = _p(2, "co-dominant leaders above the fork, the stem included", 1, 5, True)
    branches: int = _p(14, "first-order branches on the stem and leaders", 0, 200, True)
    branch_angle: float = _p(45.0, "first-order branch angle from vertical (deg)", 5.0, 90.0)
    branch_radius_ratio: float = _p(0.4, "first-order branch base radius / parent radius there", 0.05, 0.9)
    curvature: float = _p(20.0, "upward bend along a first-order branch (deg)", -60.0, 90.0)
    children: int = _p(5, "second-order branches per first-order branch", 0, 50, True)
    twigs: int = _p(4, "third-order twigs per second-order branch (0 = two branching orders)", 0, 50, True)
    leaf_area: float = _p(77.0, "one-sided leaf area of the tree (m2)", 0.0, 2000.0)
    leaf_length: float = _p(0.13, "leaf blade length (m); Eucalyptus lanceolate 0.10-0.15", 0.01, 0.5)
    leaf_width: float = _p(0.025, "leaf blade width (m)", 0.002, 0.2)
    leaf_inclination: float = _p(75.0, "mean leaf blade angle from horizontal (deg); 90 = hanging", 0.0, 90.0)
    leaf_clumping: float = _p(0.35, "fraction of each terminal twig, from its tip, that carries leaves", 0.05, 1.0)
    leaf_fill: float = _p(0.0, "share of the leaf area spread through the crown envelope's volume instead of "
                               "on the twigs (0: all on twigs)", 0.0, 1.0)
    leaf_lift: float = _p(0.0, "leaves spread through the crown (leaf_fill): 0 evenly through its volume, 1 as much in each "
                               "metre of its length (denser towards a narrow top)", 0.0, 1.0)
    min_radius: float = _p(0.003, "smallest twig radius (m)", 0.0002, 0.05)
    lean: float = _p(3.0, "random stem lean and sweep (deg)", 0.0, 30.0)
    seed: int = _p(0, "seed of this archetype's own random choices", 0, 2**31 - 1, True)
    weight: float = _p(1.0, "relative frequency with which the archetype is drawn", 0.0, 1e6)
    species: str = _p("eucalyptus", "procedural family: " + ", ".join(TREE_SPECIES), choices=TREE_SPECIES)


FIELDS = {f.name: f for f in dataclasses.fields(Archetype)}

# Ten Eucalyptus archetypes spanning the sizes of the Synthetic Forest paper's models (wood 0.3-1.4 m3,
# heights 14-29 m). Spotted gum / manna gum / stringybark-like forms: tall straight stems, a crown in
# the upper third to half, forking leaders and clumped pendulous foliage.
DEFAULT_ARCHETYPES: tuple[Archetype, ...] = (
    Archetype(height=21.0, dbh=0.30, crown_diameter=9.0, crown_ratio=0.45, branches=14, leaf_area=75, seed=1),
    Archetype(height=24.0, dbh=0.33, crown_diameter=10.0, crown_ratio=0.40, branches=15, forks=3, leaf_area=88, seed=2),
    Archetype(height=25.0, dbh=0.34, crown_diameter=9.5, crown_ratio=0.50, branches=16, taper=0.85, leaf_area=92, seed=3),
    Archetype(height=15.0, dbh=0.235, crown_diameter=7.5, crown_ratio=0.55, branches=12, fork_height=0.55, leaf_area=53, seed=4),
    Archetype(height=28.0, dbh=0.38, crown_diameter=11.0, crown_ratio=0.42, branches=18, taper=0.85, leaf_area=110, seed=5),
    Archetype(height=26.0, dbh=0.36, crown_diameter=10.5, crown_ratio=0.38, branches=16, forks=3, leaf_area=101, seed=6),
    Archetype(height=22.0, dbh=0.29, crown_diameter=8.5, crown_ratio=0.48, branches=14, branch_angle=38, leaf_area=70, seed=7),
    Archetype(height=20.0, dbh=0.32, crown_diameter=9.5, crown_ratio=0.55, branches=15, branch_angle=50, leaf_area=79, seed=8),
    Archetype(height=17.0, dbh=0.25, crown_diameter=8.0, crown_ratio=0.50, branches=12, fork_height=0.5, leaf_area=57, seed=9),
    Archetype(height=23.0, dbh=0.32, crown_diameter=9.5, crown_ratio=0.44, branches=15, curvature=30, leaf_area=84, seed=10),
)


# Blackwood-like wattles (Acacia melanoxylon / A. implexa): 8-16 m, a low fork into several leaders, a
# broad dense crown of phyllodes (lanceolate, 6-10 cm), held at middling angles.
ACACIA_ARCHETYPES: tuple[Archetype, ...] = tuple(Archetype(**{**dict(species="acacia", taper=0.8, fork_height=0.3, forks=3,
                                                           branch_angle=55, curvature=10, children=5, twigs=4,
                                                           leaf_length=0.10, leaf_width=0.018, leaf_inclination=40,
                                                           leaf_clumping=0.5, lean=6), **k}) for k in (
    dict(height=12.0, dbh=0.26, crown_diameter=8.0, crown_ratio=0.65, branches=14, leaf_area=57, seed=101),
    dict(height=9.0, dbh=0.20, crown_diameter=6.5, crown_ratio=0.70, branches=12, forks=4, leaf_area=40, seed=102),
    dict(height=15.0, dbh=0.32, crown_diameter=9.0, crown_ratio=0.60, branches=16, leaf_area=75, seed=103),
))

# Plantation Pinus radiata: one straight leader, whorls of near-horizontal branches that droop and turn
# up at their tips, a conical crown; needle fascicles are modelled as narrow shoots 15 cm long.
PINUS_ARCHETYPES: tuple[Archetype, ...] = tuple(Archetype(**{**dict(species="pinus_radiata", taper=1.0, fork_height=0.0,
                                                          forks=1, branch_angle=75, branch_radius_ratio=0.3,
                                                          curvature=-20, children=4, twigs=2, leaf_length=0.15,
                                                          leaf_width=0.015, leaf_inclination=30, leaf_clumping=0.6,
                                                          lean=1.5), **k}) for k in (
    dict(height=22.0, dbh=0.34, crown_diameter=5.5, crown_ratio=0.50, branches=40, leaf_area=66, seed=201),
    dict(height=28.0, dbh=0.42, crown_diameter=6.5, crown_ratio=0.45, branches=48, leaf_area=88, seed=202),
    dict(height=16.0, dbh=0.25, crown_diameter=4.5, crown_ratio=0.60, branches=36, leaf_area=48, seed=203),
))

FAMILY_ARCHETYPES = {"eucalyptus": DEFAULT_ARCHETYPES, "acacia": ACACIA_ARCHETYPES, "pinus_radiata": PINUS_ARCHETYPES}


def describe() -> str:
    """A table of every parameter, its default and meaning (for ``--help`` and the docs)."""
    rows = [f"{name:20s} {f.default!s:>8}  {f.metadata['meaning']}" for name, f in FIELDS.items()]
    return "\n".join(rows)


# Jucker et al. (2017): DBH ~ (height x crown diameter)^b; 0.85 lies between their angiosperm and
# gymnosperm fits (README, "Allometry check").
ALLOMETRY_EXPONENT = 0.85


def _within(name: str, value: float) -> float:
    """``value`` clipped to the bounds of the archetype field ``name``."""
    meta = FIELDS[name].metadata
    return float(min(max(value, meta["lo"]), meta["hi"]))


def grown_to(template: Archetype, height: float, crown_diameter: float, seed: int,
             leaf_area: float | None = None, crown_ratio: float | None = None) -> Archetype:
    """``template`` at another ``height`` and ``crown_diameter`` (m), with the skeleton ``seed`` (and, where
    given, its own ``crown_ratio``).

    The stem diameter scales as ``(height · crown_diameter) ** ALLOMETRY_EXPONENT`` (Jucker et al.), and
    the leaf area (unless given, m²) with the crown's volume (width² × height), so leaf area density
    stays the template's; form, branching and leaves are the template's.
    """
    height, crown_diameter = _within("height", height), _within("crown_diameter", crown_diameter)
    size = height * crown_diameter / (template.height * template.crown_diameter)
    crown_volume = (crown_diameter / template.crown_diameter) ** 2 * height / template.height
    leaf_area = template.leaf_area * crown_volume if leaf_area is None else leaf_area
    return dataclasses.replace(template, height=round(height, 3), crown_diameter=round(crown_diameter, 3),
                               dbh=round(_within("dbh", template.dbh * size ** ALLOMETRY_EXPONENT), 4),
                               leaf_area=round(_within("leaf_area", leaf_area), 2), seed=int(seed), weight=1.0,
                               **({} if crown_ratio is None else {"crown_ratio": _within("crown_ratio", crown_ratio)}))


@dataclass(frozen=True)
class UniqueTrees:
    """A ``forest.archetypes`` entry ``{species: S, unique: N}``: N distinct trees of family S in each plot,
    drawn by :func:`drawn_archetype` from the scene's seed (:func:`unique_archetypes`)."""

    species: str
    unique: int
    weight: float = 1.0


MAX_UNIQUE = 1000        # trees per unique entry: each is its own model in memory (5-11 MB of mesh arrays for the built-in archetypes)

# How a unique tree departs from its template (one of its family's built-in archetypes, drawn at random):
# a factor or an offset ``sd · z`` with z a standard normal truncated to [-2, 2], then clipped to the
# field's bounds. Height and crown diameter are relative; the crown diameter follows the drawn height
# first (same crown/height ratio as the template), and dbh and leaf area follow both (:func:`grown_to`).
RELATIVE_SPREAD = {"height": 0.15, "crown_diameter": 0.12, "branches": 0.15, "leaf_area": 0.15}
ABSOLUTE_SPREAD = {"taper": 0.05, "crown_ratio": 0.05, "fork_height": 0.05, "branch_angle": 5.0,
                   "curvature": 8.0, "leaf_inclination": 6.0, "leaf_clumping": 0.05, "lean": 1.0}


def _z(rng) -> float:
    """A standard normal draw truncated to [-2, 2] (by rejection: deterministic in ``rng``)."""
    while abs(z := float(rng.standard_normal())) > 2:
        pass
    return z


def drawn_archetype(species: str, rng, weight: float = 1.0) -> Archetype:
    """One tree of ``species`` drawn around a random built-in archetype of its family (see
    :data:`RELATIVE_SPREAD`, :data:`ABSOLUTE_SPREAD`), with its own skeleton seed."""
    family = FAMILY_ARCHETYPES[species]
    template = family[int(rng.integers(len(family)))]
    factor = {name: 1 + sd * _z(rng) for name, sd in RELATIVE_SPREAD.items()}
    offset = {name: sd * _z(rng) for name, sd in ABSOLUTE_SPREAD.items()}
    height = template.height * factor["height"]
    crown = template.crown_diameter * height / template.height * factor["crown_diameter"]
    grown = grown_to(template, height, crown, seed=int(rng.integers(0, 2**31 - 1)))
    changed = {name: round(_within(name, getattr(template, name) + d), 3) for name, d in offset.items()
               if name != "fork_height" or template.forks > 1}    # a single leader has no fork to move
    changed["branches"] = int(round(_within("branches", template.branches * factor["branches"])))
    changed["leaf_area"] = round(_within("leaf_area", grown.leaf_area * factor["leaf_area"]), 2)
    return dataclasses.replace(grown, **changed, weight=weight)


def unique_archetypes(entry: UniqueTrees, seed: int, index: int) -> tuple[Archetype, ...]:
    """The ``entry.unique`` trees of the ``index``-th ``forest.archetypes`` entry in a plot of scene seed
    ``seed``; tree i from ``seeds.rng(seed, "unique-tree", index, i)``, so the same scene gives
    the same trees and raising ``unique`` keeps the first ones. Each weighs ``entry.weight / unique``."""
    return tuple(drawn_archetype(entry.species, seeds.rng(seed, "unique-tree", index, i),
                                 weight=entry.weight / entry.unique) for i in range(entry.unique))


def expanded(archetypes, seed: int) -> tuple[Archetype, ...]:
    """A scene's ``forest.archetypes`` with each :class:`UniqueTrees` entry replaced by its drawn trees."""
    return tuple(a for i, entry in enumerate(archetypes)
                 for a in (unique_archetypes(entry, seed, i) if isinstance(entry, UniqueTrees) else (entry,)))


def nearest_template(species: str, height: float, archetypes=()) -> Archetype:
    """The archetype of ``species`` nearest in height: among ``archetypes`` (a scene's list; its
    unique-tree entries have no height and are passed over) where it has one of that species, else among
    the family's built-in ones."""
    pool = [a for a in archetypes if isinstance(a, Archetype) and a.species == species] or list(FAMILY_ARCHETYPES[species])
    return min(pool, key=lambda a: abs(a.height - height))
