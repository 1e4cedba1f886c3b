"""Placing the ground layer (``understory.grass`` and ``understory.litter``): patches on a grid of cells.

The plot is cut into :data:`~mitsuforest.specs.understory.PATCH_SIZE` m cells (the grid centred in
the plot; a plot whose sides are not whole metres keeps a strip under 1 m free at its edges); ``cover``
× the number of cells, drawn at random, each take one patch, grass first, then litter from the cells
left, so the two never overlap and the covers are met to one cell. Each patch is one of
:data:`~mitsuforest.specs.understory.PATCH_MODELS` models of its kind, turned by a multiple of 90° (so
it stays in its cell), and laid on the plane fitted to the terrain under its cell: tilted to the slope,
its centre at the plane's height there. A tilted patch's top leans out of its cell downhill as its
square's corners come in; in a cell at the plot's edge where that takes it out of the plot, it is tilted
less, just enough to stay inside the plot (its centre never moves, so patches never overlap). Patches do
not avoid trees, rocks or logs (grass grows round them). The draws use their own random stream, so a
scene without a ground layer is planned as before.
"""

from __future__ import annotations

import numpy as np

from .. import seeds
from ..specs.understory import PATCH_MODELS, PATCH_SIZE
from .types import ModelSpec, PlacedObject

FIT_SAMPLES = 5           # terrain samples per cell side for the patch's plane
LITTER_TOP = 0.02         # m: litter lies lower than this above its plane
GRASS_TOP = 1.4           # the longest blade, times understory.grass.height
TILT_STEPS = 100          # shares of a tilt tried where the whole does not fit in the plot


def ground_cells(size) -> np.ndarray:
    """(n, 2) centres of the whole :data:`PATCH_SIZE` cells that fit in a plot of ``size`` (m), the grid
    centred in the plot."""
    counts = [int(np.floor(s / PATCH_SIZE + 1e-9)) for s in size]
    axes = [(s - n * PATCH_SIZE) / 2 + (np.arange(n) + 0.5) * PATCH_SIZE for s, n in zip(size, counts)]
    gx, gy = np.meshgrid(*axes)
    return np.column_stack([gx.ravel(), gy.ravel()])


def patch_counts(understory, size) -> tuple[int, int]:
    """Grass and litter patches for the covers of ``understory`` over a plot of ``size``: each cover times
    the plot's whole cells (:func:`ground_cells`), rounded; litter takes one fewer where both round up
    past the cells there are, so covers adding up to at most 1 always fit."""
    cells = len(ground_cells(size))
    grass, litter = (int(round(cover * cells)) for cover in (understory.grass.cover, understory.litter.cover))
    if grass + litter > cells:          # both rounded up: covers add up to at most 1
        litter = cells - grass
    return grass, litter


def terrain_planes(terrain, centres: np.ndarray) -> np.ndarray:
    """(n, 3) least-squares planes ``z = h + p·dx + q·dy`` of the terrain over the cells at ``centres``
    (n, 2): the height ``h`` at the centre and the slopes ``p``, ``q``, from FIT_SAMPLES² heights per cell."""
    s = (np.arange(FIT_SAMPLES) + 0.5) / FIT_SAMPLES * PATCH_SIZE - PATCH_SIZE / 2
    dx, dy = (a.ravel() for a in np.meshgrid(s, s))
    heights = terrain.height(centres[:, :1] + dx, centres[:, 1:] + dy)          # (n, FIT_SAMPLES²)
    design = np.column_stack([np.ones_like(dx), dx, dy])
    return (np.linalg.pinv(design) @ heights.T).T


def slope_tilts(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tilts about x and y (degrees; PlacedObject.tilt) that turn +z onto the normal of planes of slopes
    ``p``, ``q`` (n,): ``Rx(a) Ry(b) ez = n`` with ``n = (-p, -q, 1)/|.|``."""
    n = np.column_stack([-p, -q, np.ones_like(p)])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.rad2deg(np.arctan2(-n[:, 1], n[:, 2])), np.rad2deg(np.arcsin(n[:, 0]))


def place_ground_layer(understory, size, terrain, seed: int) -> tuple[list[PlacedObject], dict[str, ModelSpec]]:
    """The ground layer's patches and their models (``grass01``.., ``litter01``..) for covers adding up to
    at most 1 (the scene's rule)."""
    grass, litter = patch_counts(understory, size)
    if not grass + litter:
        return [], {}
    cells = ground_cells(size)
    rng = seeds.rng(seed, "ground-layer")
    chosen = cells[rng.permutation(len(cells))[:grass + litter]]
    kinds = ["grass"] * grass + ["litter"] * litter
    tops = np.array([GRASS_TOP * understory.grass.height if k == "grass" else LITTER_TOP for k in kinds])
    planes = terrain_planes(terrain, chosen)
    tilt_x, tilt_y = _within_plot(*slope_tilts(planes[:, 1], planes[:, 2]), tops, chosen, size)
    models = {f"{kind}{i + 1:02d}": ModelSpec(kind, 1, seed=seeds.key(seed, f"{kind}-model", i, bits=31),
                                               height=understory.grass.height if kind == "grass" else None)
              for kind, n in (("grass", grass), ("litter", litter)) if n for i in range(PATCH_MODELS)}
    which = rng.integers(0, PATCH_MODELS, len(kinds))
    yaw = 90.0 * rng.integers(0, 4, len(kinds))
    objects = [PlacedObject(kind=k, model=f"{k}{int(w) + 1:02d}", treeid=0,
                            position=(float(c[0]), float(c[1]), float(h)), rotation=float(r), tilt=(float(a), float(b)))
               for k, w, c, h, r, a, b in zip(kinds, which, chosen, planes[:, 0], yaw, tilt_x, tilt_y)]
    return objects, models


def _within_plot(tilt_x: np.ndarray, tilt_y: np.ndarray, tops: np.ndarray, centres: np.ndarray, size):
    """Tilts (degrees, (n,) each) scaled down where a patch would reach out of the plot: its square, from the
    ground to ``tops`` (n,) above its plane, turned by the tilts (:func:`_reach`), must stay within its cell
    at ``centres`` (n, 2) and the cell's free margin to the plot's nearest edge along each axis. Where the
    whole tilt does not fit, the largest share of it (in steps of 1/TILT_STEPS) that does; none fits always."""
    margin = np.minimum(centres, np.asarray(size, float) - centres) - PATCH_SIZE / 2 + 1e-9      # (n, 2)
    scale = np.ones(len(tilt_x))
    tight = np.flatnonzero((_reach(tilt_x, tilt_y, tops) > margin).any(axis=1))   # cells along the plot's edges
    shares = np.linspace(1.0, 0.0, TILT_STEPS + 1)[:, None]                         # (steps, 1)
    reach = _reach(tilt_x[tight] * shares, tilt_y[tight] * shares, tops[tight])     # (steps, tight, 2)
    fits = (reach <= margin[tight]).all(axis=2)                                     # the share 0 always fits
    scale[tight] = shares[np.argmax(fits, axis=0), 0]
    return tilt_x * scale, tilt_y * scale


def _reach(tilt_x: np.ndarray, tilt_y: np.ndarray, tops: np.ndarray) -> np.ndarray:
    """(..., 2) how far beyond its cell, along x and y, a patch reaches when turned by ``Rx(tilt_x) Ry(tilt_y)``
    (degrees; turns by multiples of 90° about z change nothing): its square's corners (which a tilt draws
    in) and its top (``tops`` above its plane, which a tilt leans out)."""
    a, b = np.deg2rad(tilt_x), np.deg2rad(tilt_y)
    half = PATCH_SIZE / 2
    # Rows x and y of Rx(a) Ry(b): (cos b, 0, sin b) and (sin a sin b, cos a, -sin a cos b).
    along_x = half * np.abs(np.cos(b)) + tops * np.abs(np.sin(b))
    along_y = half * (np.abs(np.sin(a) * np.sin(b)) + np.abs(np.cos(a))) + tops * np.abs(np.sin(a) * np.cos(b))
    return np.stack([along_x, along_y], axis=-1) - half
