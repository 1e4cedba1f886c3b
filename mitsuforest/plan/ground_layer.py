"""Placing the ground layer (``understory.grass`` and ``understory.litter``): patches on a grid of cells.

The plot is cut into :data:`~mitsuforest.trees.ground_layer.PATCH_SIZE` m cells (the grid centred in
the plot); ``cover`` × the plot's area worth of cells, drawn at random, each take one patch, grass first,
then litter from the cells left, so the two never overlap and the covers are met to one cell. Each patch
is one of :data:`~mitsuforest.trees.ground_layer.PATCH_MODELS` models of its kind, turned by a multiple
of 90° (so it stays in its cell), and laid on the plane fitted to the terrain under its cell: tilted to
the slope, its centre at the plane's height there. Patches do not avoid trees, rocks or logs (grass grows
round them). The draws use their own random stream, so a scene without a ground layer is planned as
before.
"""

from __future__ import annotations

import numpy as np

from ..trees.ground_layer import PATCH_MODELS, PATCH_SIZE
from .types import ModelSpec, PlacedObject

FIT_SAMPLES = 5           # terrain samples per cell side for the patch's plane
LITTER_TOP = 0.02         # m: litter lies lower than this above its plane
GRASS_TOP = 1.4           # the longest blade, times understory.grass.height


def ground_cells(size) -> np.ndarray:
    """(n, 2) centres of the whole :data:`PATCH_SIZE` cells that fit in a plot of ``size`` (m), the grid
    centred in the plot."""
    counts = [int(np.floor(s / PATCH_SIZE + 1e-9)) for s in size]
    axes = [(s - n * PATCH_SIZE) / 2 + (np.arange(n) + 0.5) * PATCH_SIZE for s, n in zip(size, counts)]
    gx, gy = np.meshgrid(*axes)
    return np.column_stack([gx.ravel(), gy.ravel()])


def patch_counts(understory, size) -> tuple[int, int]:
    """Grass and litter patches for the covers of ``understory`` over a plot of ``size``, each cover times
    the plot's area in cells, rounded."""
    cells = size[0] * size[1] / PATCH_SIZE ** 2
    return int(round(understory.grass.cover * cells)), int(round(understory.litter.cover * cells))


def ground_layer_refusal(understory, size) -> tuple[str, str] | None:
    """``(key, reason)`` when the covers ask for more patches than the plot has whole cells, else None."""
    grass, litter = patch_counts(understory, size)
    cells = len(ground_cells(size))
    if grass + litter <= cells:
        return None
    return ("understory.litter.cover" if litter else "understory.grass.cover",
            f"{grass + litter} ground-layer patches of {PATCH_SIZE:g} m do not fit in the {cells} whole "
            f"{PATCH_SIZE:g} m cells of a {size[0]:g} x {size[1]:g} m plot; lower the covers")


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
    """The ground layer's patches and their models (``grass01``.., ``litter01``..); the covers must fit
    (:func:`ground_layer_refusal`)."""
    grass, litter = patch_counts(understory, size)
    if not grass + litter:
        return [], {}
    cells = ground_cells(size)
    rng = np.random.default_rng([int(seed), 23])
    chosen = cells[rng.permutation(len(cells))[:grass + litter]]
    kinds = ["grass"] * grass + ["litter"] * litter
    tops = np.array([GRASS_TOP * understory.grass.height if k == "grass" else LITTER_TOP for k in kinds])
    planes = terrain_planes(terrain, chosen)
    tilt_x, tilt_y = slope_tilts(planes[:, 1], planes[:, 2])
    centres = _inside(chosen, tops * np.sin(np.deg2rad(np.hypot(tilt_x, tilt_y))), size)
    heights = planes[:, 0] + planes[:, 1] * (centres[:, 0] - chosen[:, 0]) + planes[:, 2] * (centres[:, 1] - chosen[:, 1])
    models = {f"{kind}{i + 1:02d}": ModelSpec(kind, 1, seed=int(seed) * 1000 + 500 + 10 * (kind == "litter") + i,
                                               height=understory.grass.height if kind == "grass" else None)
              for kind, n in (("grass", grass), ("litter", litter)) if n for i in range(PATCH_MODELS)}
    which = rng.integers(0, PATCH_MODELS, len(kinds))
    yaw = 90.0 * rng.integers(0, 4, len(kinds))
    objects = [PlacedObject(kind=k, model=f"{k}{int(w) + 1:02d}", treeid=0,
                            position=(float(c[0]), float(c[1]), float(h)), rotation=float(r), tilt=(float(a), float(b)))
               for k, w, c, h, r, a, b in zip(kinds, which, centres, heights, yaw, tilt_x, tilt_y)]
    return objects, models


def _inside(centres: np.ndarray, lean: np.ndarray, size) -> np.ndarray:
    """(n, 2) ``centres`` moved in from the plot's edges by ``lean`` (n,): a tilted patch's top leans out
    of its cell by up to that much, and must stay in the plot."""
    reach = PATCH_SIZE / 2 + lean[:, None]
    return np.clip(centres, reach, np.asarray(size, float) - reach)
