"""Dataset files: a base scene, what varies, how many plots; drawn into one scene per plot.

>>> dataset = load_dataset("examples/dataset.yaml")        # doctest: +SKIP
>>> [p.name for p in dataset.plots], dataset.plots[0].scene.forest.trees    # doctest: +SKIP

Plot *i* draws its variations from ``seeds.rng(seed, "dataset-plot", i)``, so plot *i* is the same
whatever ``plots`` is: raising ``plots`` extends a dataset without changing the plots it has. Every
plot's scene is validated before any work; a problem is reported as ``FILE: key: reason``.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import seeds
from ..config import SCENE_SPEC, load_scene, names_builtin_sensor, read_yaml
from ..config.schema import REQUIRED, Context, Custom, FilePath, Flag, Number, Text, name_problem, parse_mapping
from ..config.types import Scene
from ..errors import ConfigError
from .tiles import tile_grid

MAX_PLOTS = 100_000
MAX_TILES_PER_PLOT = 10_000          # each tile is two files and an index row
MAX_TILES = 1_000_000                # index rows the client holds in memory
FIXED_KEYS = ("name", "output.dir")  # set by the dataset for each plot
SPLIT_NAMES = ("train", "validation", "test")

DATASET_SPEC = {
    "name": Text(None, nullable=True),
    "seed": Number(0, integer=True, ge=0),
    "base": FilePath(REQUIRED),
    "plots": Number(None, integer=True, ge=1, le=MAX_PLOTS, nullable=True),
    "vary": Custom(lambda v, c, k: _mapping(v, c, k), None),
    "grid": Custom(lambda v, c, k: _mapping(v, c, k), None),
    "tiles": Custom(lambda v, c, k: v, None),
    "splits": {name: Number(default, ge=0, le=1) for name, default in zip(SPLIT_NAMES, (0.8, 0.1, 0.1))},
    "legs_per_task": Number(None, integer=True, ge=1, nullable=True),
}
TILES_SPEC = {
    "size": Number(REQUIRED, gt=0),
    "buffer": Number(0.0, ge=0),
    "format": Text("laz", choices=("pcd", "las", "laz")),
    "plot_files": Flag(True),
}


@dataclass(frozen=True)
class Tiles:
    size: float
    buffer: float
    format: str
    plot_files: bool = True    # false: a plot split by legs gets its tiles and tables, no point files of its own


@dataclass(frozen=True)
class PlotSpec:
    """One plot of a dataset: its name, the values drawn for it (dotted scene key → value) and its scene."""

    name: str
    values: dict
    scene: Scene


@dataclass(frozen=True)
class Dataset:
    name: str
    seed: int
    file: str
    base: Scene
    plots: tuple[PlotSpec, ...]
    varied: tuple[str, ...]           # the dotted scene keys that vary, in file order
    tiles: Tiles | None
    splits: dict                      # split name → ratio
    legs_per_task: int | None
    resolved: dict                    # the dataset file with every default filled (for the manifest)

    def values_of(self, plot: str) -> dict:
        """The values drawn for a plot, by name."""
        if not hasattr(self, "_values"):
            object.__setattr__(self, "_values", {p.name: p.values for p in self.plots})
        return self._values[plot]


def load_dataset(path) -> Dataset:
    """Load and validate a dataset file and draw its plots (see module docstring).

    :raises ConfigError: ``FILE: key: reason`` for any problem, including a plot whose drawn scene
        is invalid (the message names the plot and the values drawn for it).
    """
    data, ctx = read_yaml(path)
    parsed = parse_mapping(DATASET_SPEC, data, ctx)
    name = ctx.file.stem if parsed["name"] is None else parsed["name"]
    if problem := name_problem(name):
        ctx.fail("name", problem)
    vary, grid = parsed["vary"] or {}, parsed["grid"] or {}
    ranges = {key: _variation(value, ctx, f"vary.{key}") for key, value in vary.items()}
    choices = {key: _grid_values(value, ctx, f"grid.{key}") for key, value in grid.items()}
    for key in set(ranges) & set(choices):
        ctx.fail(f"vary.{key}", "also given in grid; give each key in one of the two")
    count = _plot_count(parsed, grid, choices, ctx)
    tiles = _tiles(parsed["tiles"], ctx)
    base = load_scene(parsed["base"])
    if tiles:
        _check_tile_count(tiles, base, count, ranges, choices, ctx)
    _check_splits(parsed["splits"], ctx)
    combos = list(itertools.product(*choices.values())) or [()]
    width = max(4, len(str(count - 1)))
    plots = []
    for i in range(count):
        values = dict(zip(choices, combos[i % len(combos)]))
        rng = seeds.rng(parsed["seed"], "dataset-plot", i)
        values.update({key: variation.draw(rng) for key, variation in ranges.items()})
        values.setdefault("seed", int(rng.integers(0, 2**31 - 1)))
        name_i = f"plot_{i:0{width}d}"
        drawn = {k: v for k, v in values.items() if k in choices or k in ranges}
        plots.append(PlotSpec(name_i, values, _plot_scene(base, {**values, "name": name_i}, drawn, ctx, i)))
    if tiles and len({"pcd" in p.scene.output.formats for p in plots}) > 1:    # tiles are cut from the PCD if any
        ctx.fail("vary.output.formats" if "output.formats" in vary else "grid.output.formats",
                 "would give the plots' tiles different fields and types (a tile has those of its plot's point "
                 "files as read back: float64 coordinates from LAS, float32 from PCD); with tiles, give each "
                 "plot the same output.formats")
    if tiles and not tiles.plot_files and not parsed["legs_per_task"]:
        ctx.fail("tiles.plot_files", "false needs legs_per_task: a plot rendered in one task is cut into tiles "
                 "from its own files")
    if parsed["legs_per_task"] and any(p.scene.output.waveforms or p.scene.output.pulses for p in plots):
        ctx.fail("legs_per_task", "cannot split plots whose scene asks for output.waveforms or output.pulses "
                 "(their records are written by the process that scans the whole plot)")
    resolved = {**parsed, "name": name, "plots": count, "tiles": tiles and vars(tiles)}
    return Dataset(name, parsed["seed"], str(ctx.file.resolve()), base, tuple(plots),
                   tuple([*choices, *ranges]), tiles, dict(parsed["splits"]), parsed["legs_per_task"], resolved)


def _mapping(value, ctx: Context, key: str) -> dict:
    if value is None:
        return None
    if not isinstance(value, dict) or not value:
        ctx.fail(key, "must be a non-empty mapping of scene keys (such as forest.trees) to values")
    for name in value:
        _check_scene_key(str(name), ctx, f"{key}.{name}")
    return value


def _check_scene_key(dotted: str, ctx: Context, where: str) -> None:
    """A variation key must name a value of the scene file (not a whole section) that the dataset does
    not set itself."""
    if dotted in FIXED_KEYS:
        ctx.fail(where, f"{dotted} is set by the dataset for each plot and cannot vary")
    node, path = SCENE_SPEC, []
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            options = [".".join([*path, k]) for k in node] if isinstance(node, dict) else []
            hint = _close(".".join([*path, part]), options or _scene_keys())
            ctx.fail(where, f"unknown scene key {dotted!r}{hint}")
        node, path = node[part], [*path, part]
    if isinstance(node, dict):
        ctx.fail(where, f"{dotted} is a section; name one of its keys ({', '.join(f'{dotted}.{k}' for k in node)})")


def _scene_keys(spec=SCENE_SPEC, prefix="") -> list[str]:
    out = []
    for key, sub in spec.items():
        out += _scene_keys(sub, f"{prefix}{key}.") if isinstance(sub, dict) else [prefix + key]
    return out


def _close(word: str, options) -> str:
    import difflib
    close = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _spec_of(dotted: str):
    node = SCENE_SPEC
    for part in dotted.split("."):
        node = node[part]
    return node


@dataclass(frozen=True)
class Variation:
    """One ``vary`` entry: ``draw(rng)`` gives a plot's value; ``options`` are a choice's values (None for
    a range)."""

    draw: Callable
    options: list | None = None


def _variation(value, ctx: Context, key: str) -> Variation:
    """``{range: [lo, hi]}`` (uniform; integers when both ends are) or ``{choice: [a, b, ...]}``."""
    if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in ("range", "choice"):
        ctx.fail(key, f"must be {{range: [low, high]}} or {{choice: [a, b, ...]}}, got {value!r}")
    (kind, arg), = value.items()
    if kind == "choice":
        options = _grid_values(arg, ctx, f"{key}.choice")
        return Variation(lambda rng: options[int(rng.integers(len(options)))], options)
    if not isinstance(arg, list) or len(arg) != 2:
        ctx.fail(f"{key}.range", f"must be [low, high], got {arg!r}")
    lo, hi = (Number().parse(v, ctx, f"{key}.range[{i}]") for i, v in enumerate(arg))
    if lo > hi:
        ctx.fail(f"{key}.range", f"is empty: low {lo:g} > high {hi:g}")
    if all(isinstance(v, int) and not isinstance(v, bool) for v in arg):
        return Variation(lambda rng: int(rng.integers(lo, hi + 1)))
    return Variation(lambda rng: float(rng.uniform(lo, hi)))


def _grid_values(value, ctx: Context, key: str) -> list:
    if not isinstance(value, list) or not value:
        ctx.fail(key, f"must be a non-empty list of values, got {value!r}")
    dotted = key.split(".", 1)[1].removesuffix(".choice")
    return [_as_path(v, dotted, ctx) for v in value]


def _as_path(value, dotted: str, ctx: Context):
    """File names in a dataset file are relative to its folder (the base scene's are relative to its own)."""
    spec = _spec_of(dotted)
    if isinstance(value, str) and (isinstance(spec, FilePath) or dotted == "sensor" and not names_builtin_sensor(value)):
        return str((ctx.folder / Path(value).expanduser()).resolve())
    return value


def _plot_count(parsed: dict, grid: dict, choices: dict, ctx: Context) -> int:
    combos = int(np.prod([len(v) for v in choices.values()])) if choices else 0
    if grid and parsed["plots"] is not None and parsed["plots"] % combos:
        ctx.fail("plots", f"{parsed['plots']} is not a multiple of the grid's {combos} combinations")
    if parsed["plots"] is None and not grid:
        ctx.fail("plots", "is required (the number of plots to draw) unless a grid gives them")
    count = parsed["plots"] or combos
    if count > MAX_PLOTS:
        ctx.fail("grid", f"gives {count:,} plots; at most {MAX_PLOTS:,}")
    return count


def _tiles(value, ctx: Context) -> Tiles | None:
    if value is None:
        return None
    return Tiles(**parse_mapping(TILES_SPEC, value, ctx, "tiles"))


def _check_tile_count(tiles: Tiles, base: Scene, count: int, ranges: dict, choices: dict, ctx: Context) -> None:
    """Tiles per plot (of the base's area, or the largest area drawn) and in all must stay countable."""
    sizes = [base.area.size]
    if "area.size" in choices:
        sizes += choices["area.size"]
    if "area.size" in ranges:
        if ranges["area.size"].options is None:
            ctx.fail("vary.area.size", "an area cannot be drawn from a range; give a choice or a grid of sizes")
        sizes += ranges["area.size"].options
    per_plot = max(tile_count(size, tiles.size) for size in sizes)
    if per_plot > MAX_TILES_PER_PLOT or per_plot * count > MAX_TILES:
        ctx.fail("tiles.size", f"{tiles.size:g} m tiles make {per_plot:,} tiles per plot and {per_plot * count:,} "
                 f"in all; at most {MAX_TILES_PER_PLOT:,} per plot and {MAX_TILES:,} in all fit the index "
                 "in memory (use larger tiles or fewer plots)")


def tile_count(area_size, tile_size: float) -> int:
    nx, ny = tile_grid(area_size, tile_size)
    return nx * ny


def _check_splits(splits: dict, ctx: Context) -> None:
    total = sum(splits.values())
    if abs(total - 1) > 1e-9:
        ctx.fail("splits", "the ratios must add up to 1, got " + " + ".join(f"{v:g}" for v in splits.values())
                 + f" = {total:g}")


def _plot_scene(base: Scene, values: dict, drawn: dict, ctx: Context, i: int) -> Scene:
    """The base scene with plot ``i``'s values, validated; a problem names the dataset file, the plot and
    the values ``drawn`` for it from ``vary`` or ``grid``."""
    try:
        return base.with_(dict(values))
    except ConfigError as e:
        said = ", ".join(f"{k}={v!r}" for k, v in drawn.items())
        raise ConfigError(ctx.file, f"plot {i}", f"{said}: {e}" if said else str(e)) from None
