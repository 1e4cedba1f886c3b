"""PCD v0.7 binary point clouds (the Point Cloud Library's format), written and read with numpy."""

from __future__ import annotations

import numpy as np


_KIND = {"u": "U", "i": "I", "f": "F"}


COUNT_DIGITS = 20  # a streamed file's header is written first with its counts padded to this width


def pcd_header(dtype: np.dtype, count: int, digits: int = 0) -> str:
    """The header of a binary PCD of ``count`` points; ``digits`` zero-pads the counts, so that a
    header written before the count is known can be overwritten in place (readers parse them as
    integers: PCL, Open3D and pypcd4 accept the leading zeros)."""
    names = dtype.names
    fields = [dtype[n] for n in names]
    return "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        "FIELDS " + " ".join(names),
        "SIZE " + " ".join(str(f.itemsize) for f in fields),
        "TYPE " + " ".join(_KIND[f.kind] for f in fields),
        "COUNT " + " ".join("1" for _ in fields),
        f"WIDTH {count:0{digits}d}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {count:0{digits}d}",
        "DATA binary",
    ]) + "\n"


def read_pcd(path) -> np.ndarray:
    """Read a binary PCD (``DATA binary``), such as a render writes."""
    with open(path, "rb") as f:
        header = {}
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: no DATA line in the PCD header")
            text = line.decode("ascii").strip()
            if not text or text.startswith("#"):
                continue
            key, *values = text.split()
            header[key] = values
            if key == "DATA":
                break
        if header["DATA"][0] != "binary":
            raise ValueError(f"{path}: only DATA binary is supported, got {header['DATA'][0]}")
        kinds = {"U": "u", "I": "i", "F": "f"}
        dtype = np.dtype([(n, f"<{kinds[t]}{s}") for n, s, t in zip(header["FIELDS"], header["SIZE"], header["TYPE"])])
        count = int(header["POINTS"][0])
        return np.frombuffer(f.read(count * dtype.itemsize), dtype, count)
