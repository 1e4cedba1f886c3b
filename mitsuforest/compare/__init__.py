"""``mitsuforest compare``: two point files (PCD, LAS, LAZ; ours or another tool's) side by side.

>>> from mitsuforest.compare import compare_files                  # doctest: +SKIP
>>> result = compare_files("a.laz", "b.pcd", out_dir="out/compare")  # doctest: +SKIP
>>> result["distance"]["height_ks"]                                 # doctest: +SKIP

``metrics`` holds the measures as pure functions of numpy arrays, ``cloud`` reads any point file into
one set of fields, ``report`` describes and compares clouds, ``figure`` draws compare.png.
"""

from .cloud import Cloud, as_cloud, load_cloud
from .report import DISTANCE_KEYS, compare_clouds, compare_files, describe, format_table

__all__ = ["Cloud", "DISTANCE_KEYS", "as_cloud", "compare_clouds", "compare_files", "describe", "format_table",
           "load_cloud"]
