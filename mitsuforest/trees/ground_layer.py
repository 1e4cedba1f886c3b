"""The ground layer: square patches of grass tufts and of leaf litter, placed as instances.

A patch is :data:`PATCH_SIZE` m square, centred on the origin, its ground at z = 0. A grass patch
holds tussocks of narrow, curved blades rooted just below the ground; a litter patch holds flat
lanceolate leaves lying a few millimetres above it. The plan places a handful of patch models
(:data:`~mitsuforest.specs.understory.PATCH_MODELS` of each kind) as many times as the cover asks, so memory does not grow with the
cover. Every vertex of a patch lies inside its square, so a patch in a plot cell stays inside the plot.
Class :data:`~mitsuforest.classes.GROUND_VEGETATION` (one component).
"""

from __future__ import annotations

import numpy as np

from .. import seeds
from ..classes import GROUND_VEGETATION
from ..specs.understory import PATCH_SIZE
from .models import Model
from .understory import single_part_model

TUFTS = 36                # grass tussocks per patch
BLADES = (14, 26)         # blades per tussock (low, high inclusive)
BLADE_WIDTH = 0.006       # m at the base; blades taper to a point
BLADE_SEGMENTS = 3        # quads along a blade below its tip triangle
ROOT_DEPTH = 0.01         # m below the ground where blades start (no gap between ground and grass)
LITTER_LEAVES = 450       # leaves per litter patch
LITTER_LENGTH = (0.07, 0.15)   # m, eucalypt-like lanceolate leaves
LITTER_WIDTH = (0.015, 0.03)
LITTER_HEIGHT = (0.003, 0.008)  # m above the ground: a few millimetres


def blade_strips(roots: np.ndarray, azimuth: np.ndarray, lean: np.ndarray, length: np.ndarray,
                 droop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tapered, curved grass blades.

    :param roots: (k, 3) blade roots; ``azimuth``, ``lean`` (rad from vertical at the root), ``length``
        (m) and ``droop`` (rad of extra lean gained toward the tip): (k,) each.
    :returns: vertices (k·(2·BLADE_SEGMENTS + 3), 3) and faces (k·(2·BLADE_SEGMENTS + 1), 3): per blade
        ``BLADE_SEGMENTS + 1`` left/right pairs along it, then the tip.
    """
    k, n = len(roots), BLADE_SEGMENTS + 1
    s = np.linspace(0.0, 1.0, n + 1)                                   # stations, the last is the tip
    angle = lean[:, None] + droop[:, None] * s[None, :] ** 2           # (k, n+1) from vertical
    step = length[:, None] / n
    horizontal = np.concatenate([np.zeros((k, 1)), np.cumsum(step * np.sin(angle[:, :-1]), 1)], 1)
    vertical = np.concatenate([np.zeros((k, 1)), np.cumsum(step * np.cos(angle[:, :-1]), 1)], 1)
    out = np.stack([np.cos(azimuth), np.sin(azimuth)], 1)              # (k, 2)
    axis = np.empty((k, n + 1, 3))
    axis[..., :2] = roots[:, None, :2] + horizontal[..., None] * out[:, None, :]
    axis[..., 2] = roots[:, None, 2] + vertical
    side = np.column_stack([-out[:, 1], out[:, 0], np.zeros(k)])       # across the blade, horizontal
    half = BLADE_WIDTH / 2 * (1 - s[:-1])                              # (n,) tapering
    left = axis[:, :-1] - side[:, None, :] * half[None, :, None]
    right = axis[:, :-1] + side[:, None, :] * half[None, :, None]
    pairs = np.stack([left, right], 2).reshape(k, 2 * n, 3)
    vertices = np.concatenate([pairs, axis[:, -1:]], 1)                # (k, 2n+1, 3)
    per = 2 * n + 1
    quads = [[2 * i, 2 * i + 1, 2 * i + 3] for i in range(n - 1)] + [[2 * i, 2 * i + 3, 2 * i + 2] for i in range(n - 1)]
    local = np.array(quads + [[2 * n - 2, 2 * n - 1, 2 * n]])
    faces = (per * np.arange(k)[:, None, None] + local[None]).reshape(-1, 3)
    return vertices.reshape(-1, 3), faces


def grass_patch_model(seed: int, name: str, height: float = 0.3) -> Model:
    """A :data:`PATCH_SIZE` m grass patch: :data:`TUFTS` tussocks of narrow blades (mean blade length
    ``height`` m), each blade leaning out 5-40° and drooping toward its tip; every vertex within the
    square (|x|, |y| ≤ PATCH_SIZE/2): a blade that would lean out of it is drawn in toward its root."""
    rng = seeds.rng(seed, "grass")
    counts = rng.integers(BLADES[0], BLADES[1] + 1, TUFTS)
    k = int(counts.sum())
    centres = rng.uniform(-PATCH_SIZE / 2 + 0.03, PATCH_SIZE / 2 - 0.03, (TUFTS, 2))
    tuft = np.repeat(np.arange(TUFTS), counts)
    roots = np.column_stack([centres[tuft] + rng.normal(0, 0.01, (k, 2)).clip(-0.025, 0.025), np.full(k, -ROOT_DEPTH)])
    vertices, faces = blade_strips(roots, rng.uniform(0, 2 * np.pi, k), np.deg2rad(rng.uniform(5, 40, k)),
                                   height * rng.uniform(0.6, 1.4, k), np.deg2rad(rng.uniform(10, 50, k)))
    return single_part_model(name, "grass", GROUND_VEGETATION, [(_kept_in_square(vertices, roots), faces)],
                             meta={"tufts": TUFTS, "blades": k, "height": height})


def _kept_in_square(vertices: np.ndarray, roots: np.ndarray) -> np.ndarray:
    """Blade ``vertices`` (k·m, 3), ``m`` per blade, with each blade's horizontal reach from its root
    (k, 3) scaled down just enough that it stays in the patch's square."""
    k = len(roots)
    v = vertices.reshape(k, -1, 3).copy()
    off = v[..., :2] - roots[:, None, :2]
    room = np.where(off > 0, PATCH_SIZE / 2 - roots[:, None, :2], -PATCH_SIZE / 2 - roots[:, None, :2])
    with np.errstate(divide="ignore", invalid="ignore"):
        allowed = np.where(np.abs(off) > 1e-12, room / off, np.inf)
    scale = np.clip(allowed.min(axis=(1, 2)), 0.0, 1.0)
    v[..., :2] = roots[:, None, :2] + off * scale[:, None, None]
    return v.reshape(-1, 3)


def litter_patch_model(seed: int, name: str) -> Model:
    """A :data:`PATCH_SIZE` m patch of leaf litter: :data:`LITTER_LEAVES` flat lanceolate leaves (two
    triangles each) lying :data:`LITTER_HEIGHT` above the ground, tilted at most 5°, each wholly
    inside the square."""
    rng = seeds.rng(seed, "litter")
    k = LITTER_LEAVES
    length, width = rng.uniform(*LITTER_LENGTH, k), rng.uniform(*LITTER_WIDTH, k)
    az = rng.uniform(0, 2 * np.pi, k)
    along = np.column_stack([np.cos(az), np.sin(az), np.zeros(k)])
    across = np.column_stack([-np.sin(az), np.cos(az), np.zeros(k)])
    tilt = np.tan(np.deg2rad(rng.uniform(-5, 5, k)))
    margin = LITTER_LENGTH[1] / 2
    centre = np.column_stack([rng.uniform(-PATCH_SIZE / 2 + margin, PATCH_SIZE / 2 - margin, (k, 2)),
                              rng.uniform(*LITTER_HEIGHT, k)])
    half = (length / 2)[:, None]
    base = centre - along * half
    tip = centre + along * half
    base[:, 2] -= (tilt * length / 2).clip(max=centre[:, 2] - 0.001)  # the low end stays above the ground
    tip[:, 2] += tilt * length / 2
    tip[:, 2] = np.maximum(tip[:, 2], 0.001)
    mid = base + (tip - base) * 0.4
    left, right = mid - across * (width / 2)[:, None], mid + across * (width / 2)[:, None]
    vertices = np.stack([base, left, tip, right], 1).reshape(-1, 3)
    i = 4 * np.arange(k)[:, None]
    faces = np.concatenate([i + [0, 1, 3], i + [1, 2, 3]], 1).reshape(-1, 3)
    return single_part_model(name, "litter", GROUND_VEGETATION, [(vertices, faces)], meta={"leaves": k})


def covered_share(model: Model, pixels: int = 4000) -> float:
    """The share of a patch's square that its triangles cover seen from straight above: the triangles
    filled into a ``pixels`` × ``pixels`` raster of the square (0.25 mm cells at the default), which is
    what a nadir beam finds there instead of the ground."""
    from PIL import Image, ImageDraw
    image = Image.new("1", (pixels, pixels), 0)
    draw = ImageDraw.Draw(image)
    v = (model.vertices()[:, :2] / PATCH_SIZE + 0.5) * pixels
    offset = 0
    for part in model.parts:
        for tri in v[offset:offset + len(part.vertices)][part.faces.astype(np.int64)]:
            draw.polygon([tuple(p) for p in tri], fill=1)
        offset += len(part.vertices)
    return float(np.asarray(image, bool).mean())
