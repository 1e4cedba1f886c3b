"""Point rasters for the quick-look pictures, accumulated batch by batch in numpy.

:class:`TopView` keeps the class of the highest point of each pixel over the plot; :class:`SideTile`
keeps the points of the central 20 m tile for its front views (:func:`front_view`). Drawing points is
plain array indexing, so tens of millions of points cost seconds; ``write/figures.py`` frames the
rasters with axes, scale and legends.
"""

from __future__ import annotations

import copy

import numpy as np
from PIL import Image

from .. import seeds
from ..classes import BUSH, DEADWOOD, GROUND, GROUND_VEGETATION, ROCK, STUMP, TREE_LEAVES, TREE_WOOD
from .atomic import atomic_path

CLASS_RGB = {GROUND: (196, 178, 140), TREE_WOOD: (120, 72, 40), TREE_LEAVES: (60, 160, 60),
             DEADWOOD: (200, 60, 200), ROCK: (110, 110, 120), STUMP: (230, 150, 40), BUSH: (150, 210, 90),
             GROUND_VEGETATION: (205, 215, 60)}
OTHER_RGB = (60, 60, 200)      # a class without a colour of its own
CLASS_COLOURS = np.array([CLASS_RGB.get(c, OTHER_RGB) for c in range(256)], np.uint8)   # index = class code
WOODY_CLASSES = (TREE_WOOD, DEADWOOD, STUMP)
TILE_FIELDS = ("x", "y", "z", "classification", "instance", "treeid")


def instance_colours(instance: np.ndarray) -> np.ndarray:
    """A stable, distinct colour per instance id (ground, instance 0, grey)."""
    return instance_palette(int(instance.max(initial=0)))[instance]


def instance_palette(largest: int) -> np.ndarray:
    """(largest + 1, 3) colours, the same for an id whatever ``largest`` is; id 0 grey."""
    rng = seeds.rng(0, "instance-colours")
    palette = rng.integers(40, 230, (max(largest, 0) + 1, 3)).astype(np.uint8)
    palette[0] = 170
    return palette


class TopView:
    """Top view coloured by class, accumulated batch by batch: each pixel shows its highest point."""

    def __init__(self, area, pixels_per_m: float = 20.0, max_pixels: int = 1000):
        w, h = area
        self.area = (float(w), float(h))
        self.scale = min(pixels_per_m, max_pixels / max(w, h, 1e-9))
        self.size = (max(int(w * self.scale), 2), max(int(h * self.scale), 2))
        self.top = np.full(self.size[1] * self.size[0], -np.inf, np.float32)
        self.cls = np.zeros(self.size[1] * self.size[0], np.uint8)

    def add(self, points) -> None:
        if len(points) == 0:
            return
        pix, z = self._pixels(points)
        np.maximum.at(self.top, pix, z)
        highest = np.flatnonzero(z >= self.top[pix])     # the points now on top of their pixel
        self.cls[pix[highest]] = points["classification"][highest]

    def _pixels(self, points) -> tuple[np.ndarray, np.ndarray]:
        w, h = self.size
        i = np.clip((points["x"] * np.float32(self.scale)).astype(np.int32), 0, w - 1)
        j = np.clip(((np.float32(self.area[1]) - points["y"]) * np.float32(self.scale)).astype(np.int32), 0, h - 1)
        return j * np.int32(w) + i, points["z"].astype(np.float32)

    def part(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The top of ``points`` alone, for :meth:`merge` (parts of the points can be viewed side by
        side): the pixels they fall in (k,), each one's highest z (k,) and the class of its last point at
        that height (k,)."""
        pix, z = self._pixels(points)
        pixels, inverse = np.unique(pix, return_inverse=True)
        top = np.full(len(pixels), -np.inf, np.float32)
        np.maximum.at(top, inverse, z)
        cls = np.zeros(len(pixels), np.uint8)
        highest = np.flatnonzero(z >= top[inverse])
        cls[inverse[highest]] = points["classification"][highest]
        return pixels, top, cls

    def merge(self, part: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Add a :meth:`part`, as :meth:`add` would have added its points (parts merged in order)."""
        pixels, top, cls = part
        on_top = top >= self.top[pixels]
        self.top[pixels] = np.maximum(self.top[pixels], top)
        self.cls[pixels[on_top]] = cls[on_top]

    def image(self, fill_m: float = 0.5) -> np.ndarray:
        """(h, w, 3) uint8, north up. A pixel no point fell in takes the class of the nearest pixel one did
        within ``fill_m`` (the gaps between scan lines, narrower than a metre, are no no-data stripes);
        farther ones stay white."""
        from scipy.ndimage import distance_transform_edt
        shape = (self.size[1], self.size[0])
        empty = ~np.isfinite(self.top).reshape(shape)
        cls = self.cls.reshape(shape)
        if empty.all():
            return np.full((*shape, 3), 255, np.uint8)
        distance, (rows, cols) = distance_transform_edt(empty, return_indices=True)
        img = CLASS_COLOURS[cls[rows, cols]]
        img[distance > fill_m * self.scale] = 255
        return img


class SideTile:
    """The points of the central 20 m x 20 m tile (at most the plot), for its front views."""

    def __init__(self, area, tile: float = 20.0):
        w, h = area
        self.tile = min(tile, w, h)
        self.x0, self.y0 = (w - self.tile) / 2, (h - self.tile) / 2
        self.parts = []
        self.stored_at = None       # the file of :meth:`stored`

    @property
    def x_range(self) -> tuple[float, float]:
        return self.x0, self.x0 + self.tile

    def outline(self) -> SideTile:
        """The tile's place without its points: what the top view outlines, cheap to send to a worker."""
        out = copy.copy(self)
        out.parts, out.stored_at = [], None
        return out

    def stored(self, path) -> SideTile:
        """The tile with its points saved to the ``.npy`` file ``path`` (in shared memory, say) and read
        back from there by :meth:`points`: cheap to send to a worker, where a pickle of the points would
        cost the sender a copy under Python's lock and a pipe (93 MB for the open scene's thin beam)."""
        np.save(path, self.points())
        out = self.outline()
        out.stored_at = str(path)
        return out

    def add(self, points) -> None:
        self.parts.append(self.select(points))

    def select(self, points) -> np.ndarray:
        """The part of ``points`` that :meth:`add` keeps: those in the tile, with the fields it draws, packed
        (31 bytes a point of the scan's: a selection of fields alone keeps the whole record's 72, which a
        writer worker then pickled back with its part)."""
        sel = ((points["x"] >= self.x0) & (points["x"] < self.x0 + self.tile)
               & (points["y"] >= self.y0) & (points["y"] < self.y0 + self.tile))
        fields = [f for f in TILE_FIELDS if f in points.dtype.names]
        return points[sel][fields].astype([(f, points.dtype[f]) for f in fields])

    def points(self) -> np.ndarray:
        if self.stored_at:
            return np.load(self.stored_at)
        if self.parts:
            return np.concatenate(self.parts)
        return np.zeros(0, [("x", "f4"), ("y", "f4"), ("z", "f4"), ("classification", "u1"), ("instance", "u4"),
                            ("treeid", "u2")])


def front_view(points, x_range, z_range, colours: np.ndarray, pixels_per_m: float = 20.0) -> np.ndarray:
    """Points seen from the south (x across, z up; each pixel shows its nearest point, smallest y), as an
    (h, w, 3) uint8 image over ``x_range`` x ``z_range``; ``colours`` is (n, 3), one per point."""
    shape, pixels, rows = front_points(points, x_range, z_range, pixels_per_m)
    return paint(shape, pixels, colours[rows])


def front_points(points, x_range, z_range, pixels_per_m: float = 20.0) -> tuple[tuple[int, int], np.ndarray, np.ndarray]:
    """What :func:`front_view` draws: the image's (h, w), and the points in front (the nearest of their
    pixel), as their flat pixel indices (k,) and their rows in ``points`` (k,), in the points' order.
    Views of the same points in other colours share them (:func:`paint`)."""
    (x0, x1), (z0, z1) = x_range, z_range
    w, h = max(int((x1 - x0) * pixels_per_m), 2), max(int((z1 - z0) * pixels_per_m), 2)
    if len(points) == 0:
        return (h, w), np.zeros(0, np.int64), np.zeros(0, np.int64)
    i = np.clip(((points["x"] - x0) * pixels_per_m).astype(np.int64), 0, w - 1)
    j = np.clip(((z1 - points["z"]) * pixels_per_m).astype(np.int64), 0, h - 1)
    pix = j * w + i
    nearest = np.full(h * w, np.inf)
    np.minimum.at(nearest, pix, points["y"].astype(np.float64))
    rows = np.flatnonzero(points["y"] <= nearest[pix])
    return (h, w), pix[rows], rows


def paint(shape: tuple[int, int], pixels: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """An (h, w, 3) uint8 white image with ``colours`` (k, 3) at the flat ``pixels`` (k,) (where two share
    a pixel, the later one)."""
    img = np.full((*shape, 3), 255, np.uint8)
    img.reshape(-1, 3)[pixels] = colours
    return img


def write_png(path, image: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
