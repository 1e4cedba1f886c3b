"""Quick-look pictures: a top view coloured by class and a side view of a tile coloured by instance."""

from __future__ import annotations

import numpy as np
from PIL import Image

from .atomic import atomic_path

CLASS_COLOURS = np.array([
    [0, 0, 0], [166, 124, 82], [120, 72, 40], [60, 160, 60], [200, 60, 200], [150, 150, 150],
    [230, 150, 40], [150, 210, 90]], np.uint8)  # index = class code; 0 unused


def _raster(u, v, value_rgb, order, size, extent, background=255):
    """Draw points (u, v) in ``order`` (later on top) into an RGB image of ``size`` pixels."""
    w, h = size
    (u0, u1), (v0, v1) = extent
    i = np.clip(((u - u0) / max(u1 - u0, 1e-9) * (w - 1)).astype(int), 0, w - 1)
    j = np.clip(((v1 - v) / max(v1 - v0, 1e-9) * (h - 1)).astype(int), 0, h - 1)
    img = np.full((h, w, 3), background, np.uint8)
    img[j[order], i[order]] = value_rgb[order]
    return img


def instance_colours(instance: np.ndarray) -> np.ndarray:
    """A stable, distinct colour per instance id (ground, instance 0, grey)."""
    rng = np.random.default_rng(12345)
    palette = rng.integers(40, 230, (int(instance.max(initial=0)) + 1, 3)).astype(np.uint8)
    palette[0] = 170
    return palette[instance]


class TopView:
    """Top view coloured by class, accumulated batch by batch: each pixel shows its highest point."""

    def __init__(self, area, pixels_per_m: float = 20.0, max_pixels: int = 2000):
        w, h = area
        self.height_m = h
        self.scale = min(pixels_per_m, max_pixels / max(w, h, 1e-9))
        self.size = (max(int(w * self.scale), 2), max(int(h * self.scale), 2))
        self.top = np.full(self.size[1] * self.size[0], -np.inf)
        self.cls = np.zeros(self.size[1] * self.size[0], np.uint8)

    def add(self, points) -> None:
        if len(points) == 0:
            return
        w, h = self.size
        i = np.clip((points["x"] * self.scale).astype(int), 0, w - 1)
        j = np.clip(((self.height_m - points["y"]) * self.scale).astype(int), 0, h - 1)
        pix = j * w + i
        z = points["z"]
        # One sort by pixel, then height within the pixel (z scaled into [0, 0.5) as the fraction).
        span = float(z.max() - z.min()) + 1.0
        order = np.argsort(pix + (z - z.min()) / (2 * span))
        last = np.r_[pix[order][1:] != pix[order][:-1], True]   # the highest point of each pixel
        sel = order[last]
        higher = z[sel] > self.top[pix[sel]]
        self.top[pix[sel][higher]] = z[sel][higher]
        self.cls[pix[sel][higher]] = points["classification"][sel][higher]

    def image(self) -> np.ndarray:
        img = CLASS_COLOURS[self.cls].reshape(self.size[1], self.size[0], 3).copy()
        img[~np.isfinite(self.top).reshape(self.size[1], self.size[0])] = 255
        return img


class SideTile:
    """The points of the central 20 m x 20 m tile (at most), for a side view by instance."""

    def __init__(self, area, tile: float = 20.0):
        w, h = area
        self.tile = min(tile, w, h)
        self.x0, self.y0 = (w - self.tile) / 2, (h - self.tile) / 2
        self.parts = []

    def add(self, points) -> None:
        sel = ((points["x"] >= self.x0) & (points["x"] < self.x0 + self.tile)
               & (points["y"] >= self.y0) & (points["y"] < self.y0 + self.tile))
        self.parts.append(points[sel][["x", "y", "z", "instance"]])

    def image(self) -> np.ndarray:
        pts = np.concatenate(self.parts) if self.parts else np.zeros(0, [("x", "f8"), ("y", "f8"), ("z", "f8"),
                                                                         ("instance", "u4")])
        return side_view(pts, (self.x0, self.x0 + self.tile))


def side_view(points, x_range, pixels_per_m: float = 30.0) -> np.ndarray:
    """Points with x in ``x_range`` seen from the south: y would be depth, so draw x against z."""
    sel = points[(points["x"] >= x_range[0]) & (points["x"] < x_range[1])]
    if len(sel) == 0:
        return np.full((10, 10, 3), 255, np.uint8)
    z0, z1 = float(sel["z"].min()), float(sel["z"].max())
    size = (max(int((x_range[1] - x_range[0]) * pixels_per_m), 2), max(int((z1 - z0) * pixels_per_m), 2))
    order = np.argsort(-sel["y"], kind="stable")  # nearest (smallest y) drawn last
    return _raster(sel["x"], sel["z"], instance_colours(sel["instance"]), order, size, (x_range, (z0, z1)))


def write_png(path, image: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
