"""Trees from files: the entries of ``forest.models`` in a scene file (see README, "Your own trees").

A :class:`MeshTree` names a mesh (one file split into wood and leaves by name patterns, or two files);
a :class:`QsmTree` names a cylinder table and the procedural leaves to hang on it. Both are frozen and
hashable, like :class:`~.archetypes.Archetype`; their files' contents (not their paths) key the model
cache, see :func:`content_hash`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

from ..errors import ConfigError, display_path

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UP_AXES = ("z", "y")
REPAIR_MODES = ("fix", "skip")
DEFAULT_LEAF_PATTERNS = ("*leaf*", "*leaves*", "*foliage*", "*needle*")
MIN_HEIGHT, MAX_HEIGHT = 0.1, 150.0   # m: outside this an imported tree has the wrong units
MAX_RADIUS = 10.0                      # m: a QSM cylinder wider than this (the widest stems are ~5 m) has the wrong units


@dataclass(frozen=True)
class MeshTree:
    """A tree mesh: ``mesh`` split by ``leaves`` name patterns, or the two files ``wood`` and ``leaves``."""

    mesh: str | None = None            # one file holding wood and leaves
    wood: str | None = None            # or the wood file ...
    leaves: tuple[str, ...] | str | None = DEFAULT_LEAF_PATTERNS   # ... patterns (with mesh) or the leaves file
    units: str = "m"                   # m, cm or mm
    up: str = "z"                      # the file's up axis: z or y
    repair: str = "fix"                # fix: a part that cannot be repaired is an error; skip: left out of the volume
    weight: float = 1.0

    @property
    def files(self) -> tuple[str, ...]:
        if self.mesh:
            return (self.mesh,)
        return (self.wood,) + ((self.leaves,) if isinstance(self.leaves, str) else ())

    @property
    def source(self) -> str:
        return self.mesh or self.wood


@dataclass(frozen=True)
class QsmTree:
    """A quantitative structure model (cylinder table) with procedural leaves on its branch tips."""

    qsm: str
    units: str = "m"
    up: str = "z"
    leaf_area: float = 35.0            # one-sided leaf area of the tree (m²); 0: no leaves
    leaf_length: float = 0.13
    leaf_width: float = 0.025
    leaf_inclination: float = 65.0
    leaf_clumping: float = 0.5
    seed: int = 0                      # of the leaves' random placement
    weight: float = 1.0

    @property
    def files(self) -> tuple[str, ...]:
        return (self.qsm,)

    @property
    def source(self) -> str:
        return self.qsm


def content_hash(paths) -> str:
    """SHA-256 of the files' bytes and kinds (suffixes), in order, each followed by the files it reads
    (an OBJ's ``mtllib``, a glTF's buffers; a missing one counts as missing): a renamed or moved file
    keeps its cache entry, while an edited material or buffer file, or a new suffix, does not."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(Path(path).suffix.lower().encode() + b"\0kind\0")
        try:
            _hash_file(digest, path)
            for companion in companion_files(path):
                if Path(companion).is_file():
                    _hash_file(digest, companion)
                else:
                    digest.update(b"\0missing\0" + Path(companion).name.encode())
        except OSError as e:   # unreadable (permissions): bad input, not a failing write
            raise ModelFileError(e.filename or path, "", f"cannot be read ({e.strerror or e})") from None
        digest.update(b"\0file\0")
    return digest.hexdigest()


def _hash_file(digest, path) -> None:
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)


def companion_files(path) -> list[Path]:
    """The files a mesh file reads beside itself: an OBJ's material libraries, a glTF's buffers."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        with open(path, "rb") as f:
            names = [n for line in f if line.startswith(b"mtllib") for n in line.split()[1:]]
        return [path.parent / n.decode("utf-8", "replace") for n in names]
    if suffix == ".gltf":
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError):
            return []   # the reader reports it
        buffers = document.get("buffers") if isinstance(document, dict) else None   # else not glTF: the reader says so
        uris = [b.get("uri") for b in buffers if isinstance(b, dict)] if isinstance(buffers, list) else []
        return [path.parent / unquote(u) for u in uris if isinstance(u, str) and u and not u.startswith("data:")]
    return []


def missing_companions(path) -> list[Path]:
    """The :func:`companion_files` of ``path`` that are not there."""
    return [p for p in companion_files(path) if not p.is_file()]


def source_name(entry) -> str:
    return Path(entry.source).name


class ModelFileError(ConfigError):
    """A tree file that cannot be used, reported as ``FILE: where: reason`` (``where`` may be empty)."""

    def __init__(self, path, where: str, reason: str):
        super().__init__(display_path(path), where, reason)
