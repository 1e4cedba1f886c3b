"""Writes ``examples/data/dem.tif``, the small DEM of ``examples/dem.yaml``: 60 m x 60 m at 0.5 m cells
(120 x 120 float32, deflate-compressed), north-up in GDA2020 / MGA zone 55 (EPSG:7855), its SW corner at
E 320,000 m, N 5,810,000 m. The surface: a 4 m hill in the north-east, a 1.5 m deep gully running
south-west, on a plane rising 3 m to the east, about 180 m above the datum; nothing random, so running
this again writes the same heights. Run it from anywhere: ``python examples/data/make_dem.py``.
"""

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine

EAST, NORTH = 320_000.0, 5_810_000.0   # SW corner (m, EPSG:7855)
CELL, CELLS = 0.5, 120                  # m, cells a side


def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Height (m) at local x, y (m from the SW corner), arrays of one shape."""
    hill = 4.0 * np.exp(-((x - 42.0) ** 2 + (y - 40.0) ** 2) / (2 * 9.0 ** 2))
    gully = -1.5 * np.exp(-((x - y + 8.0) / np.sqrt(2)) ** 2 / (2 * 3.0 ** 2))
    return 180.0 + 0.05 * x + hill + gully


def main(path=Path(__file__).with_name("dem.tif")) -> Path:
    centres = (np.arange(CELLS) + 0.5) * CELL
    x, y = np.meshgrid(centres, centres[::-1])          # rows run south (north-up)
    z = surface(x, y).astype(np.float32)
    profile = dict(driver="GTiff", width=CELLS, height=CELLS, count=1, dtype="float32", crs="EPSG:7855",
                   transform=Affine(CELL, 0, EAST, 0, -CELL, NORTH + CELLS * CELL), compress="deflate",
                   predictor=3)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z, 1)
    return path


if __name__ == "__main__":
    print(main())
