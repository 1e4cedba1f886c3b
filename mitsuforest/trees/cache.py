"""Disk cache of models, keyed by their parameters and by the code that generates them.

Location: ``$MITSUFOREST_CACHE`` or ``~/.cache/mitsuforest``. Delete the folder to clear it. Beside
the models, ``models/derived/`` keeps what the scan computes from a cached model's meshes
(:class:`DerivedArrays`).

Size: about ``$MITSUFOREST_CACHE_SIZE`` (``20G`` unless set; ``unlimited`` for no bound). A process that
stores an entry past the bound removes the entries read longest ago (a read sets an entry's access time)
until the cache holds :data:`EVICT_TO` of it, one process at a time (:func:`_evict`); each process counts the
folder again once its own stores since pass :data:`RECOUNT` of the bound. The keys change with the code and
with every calibrated or unique tree, so entries nobody reads again pile up (this project's cache reached
61 GB).

The key hashes the model's parameters together with :func:`code_hash`: the source of the
generating modules and the versions of the libraries they call, so editing a generator or
upgrading a library makes new entries without anyone bumping a version number. The cache is best
effort: a damaged entry is rebuilt, and a cache that cannot be written (read-only, full, not a
folder) costs one warning per process and the time of building models anew.
"""

from __future__ import annotations

import collections
import contextlib
import copy
import dataclasses
import functools
import hashlib
import importlib.metadata
import json
import logging
import math
import os
import sys
import time
import zipfile
from pathlib import Path

try:
    import fcntl
except ImportError:     # not POSIX: evictions are not serialised between processes
    fcntl = None

import numpy as np

from ..errors import UserError
from .models import Component, Model, Part
from .volume import WoodVolume

log = logging.getLogger(__name__)

NOT_GENERATORS = ("cache.py", "gallery.py", "parallel.py")    # trees/ modules that make no geometry
# Package modules outside trees/ whose source decides a model's bytes: the component classes stored with
# each model, and the seeding (a model's random streams come from seeds.rng).
GENERATOR_MODULES = ("classes.py", "seeds.py")
# Libraries whose results a model's bytes hold, so their versions are in the key: pymeshfix repairs imported
# wood (trees/repair.py), scipy finds the loose parts for trimesh (trimesh.graph.connected_components).
GENERATOR_LIBRARIES = ("numpy", "trimesh", "manifold3d", "pymeshfix", "scipy")
LOAD_ERRORS = (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile)

_write_failed = False   # set once a write failed, so the warning is given once per process
SIZE_VARIABLE = "MITSUFOREST_CACHE_SIZE"
DEFAULT_SIZE = "20G"
EVICT_TO = 0.8          # an eviction leaves the cache at this share of its bound, so the next store does not scan
RECOUNT = 0.05          # a process counts the cache again once its own stores since the last count pass this share
UNITS = {"K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}
# Per cache folder: its size when this process last counted it (None: not yet, or another process was
# evicting), and the bytes this process has stored since.
_cache_bytes: dict[Path, tuple[int | None, int]] = {}
MEMORY_ENTRIES = 64     # models kept in memory per process (see :func:`cached`)
# Per entry path: the entry's state (path, modification time, size) when read or stored, and its model.
_in_memory: collections.OrderedDict[str, tuple[tuple, Model]] = collections.OrderedDict()


def cache_dir() -> Path:
    return Path(os.environ.get("MITSUFOREST_CACHE", Path.home() / ".cache" / "mitsuforest")) / "models"


def cache_limit() -> int | None:
    """The cache's bound in bytes from ``$MITSUFOREST_CACHE_SIZE`` (:data:`DEFAULT_SIZE` unless set): a
    number of bytes with an optional K, M, G or T (powers of 1024), or ``unlimited`` (None).

    :raises UserError: for any other value, or a bound under 1 MB.
    """
    text = (os.environ.get(SIZE_VARIABLE, "").strip() or DEFAULT_SIZE).upper().removesuffix("B")
    if text == "UNLIMITED":
        return None
    number, unit = (text[:-1], UNITS[text[-1]]) if text[-1:] in UNITS else (text, 1)
    try:
        size = float(number) * unit
    except ValueError:
        size = math.nan
    if not size >= 2 ** 20 or not math.isfinite(size):
        raise UserError(f"{SIZE_VARIABLE}: must be a size of 1M or more (bytes, or with K, M, G or T: 20G) or "
                        f"'unlimited', got {os.environ.get(SIZE_VARIABLE)!r}")
    return int(size)


@functools.cache
def code_hash() -> str:
    """A hash of everything besides the parameters that decides a model's geometry: the source of
    ``mitsuforest/trees/*.py`` (less :data:`NOT_GENERATORS`) and of :data:`GENERATOR_MODULES`, and the
    versions of :data:`GENERATOR_LIBRARIES`."""
    trees = Path(__file__).parent
    sources = [p for p in sorted(trees.glob("*.py")) if p.name not in NOT_GENERATORS]
    digest = hashlib.sha256()
    for path in [*sources, *(trees.parent / name for name in GENERATOR_MODULES)]:
        digest.update(f"{path.name}\0".encode() + path.read_bytes() + b"\0")
    for dist in GENERATOR_LIBRARIES:
        digest.update(f"{dist}={importlib.metadata.version(dist)}\0".encode())
    return digest.hexdigest()[:20]


def cache_key(kind: str, params: dict) -> str:
    text = json.dumps({"kind": kind, "params": params, "code": code_hash()}, sort_keys=True)
    return f"{kind}-{hashlib.sha256(text.encode()).hexdigest()[:20]}"


def _entry_path(kind: str, params: dict) -> Path:
    return cache_dir() / (cache_key(kind, params) + ".npz")


def is_stored(kind: str, params: dict) -> bool:
    """Whether the cache holds an entry for ``(kind, params)`` (readable or not: a damaged one is rebuilt
    where it is read)."""
    return _entry_path(kind, params).is_file()


def cached(kind: str, params: dict, build) -> Model:
    """Load the model for ``(kind, params)`` from the cache, or ``build()`` it and try to store it.

    A process keeps the last :data:`MEMORY_ENTRIES` models it loaded or built (their arrays read-only)
    and hands out copies sharing them: a dataset worker renders plot after plot of the same
    archetypes without reading them again."""
    path = _entry_path(kind, params)
    model = _from_memory(path)
    if model is not None:
        _used(path)                             # still in use: not the first to go when the cache is full
    else:
        with contextlib.suppress(*LOAD_ERRORS):  # no entry yet, or an unreadable or damaged one: build it
            model = _load(path)
    if model is None:
        model = build()
        model.hull_corners()
        _store(_model_arrays(model), path)
    _remember(_entry_state(path), model, path)
    return _copy(model)


def cached_arrays(kind: str, params: dict, names: tuple[str, ...], build) -> dict[str, np.ndarray]:
    """Load the arrays ``names`` for ``(kind, params)`` from the cache, or ``build()`` them (a dict of
    those names to arrays) and try to store them: what is worth keeping besides a model itself (an
    archetype's crown, which a plan needs before any model is built)."""
    path = _entry_path(kind, params)
    arrays = _read(path, names)
    if arrays is None:
        arrays = build()
        _store(arrays, path)
    return arrays


def _read(path: Path, names: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """The arrays ``names`` of the entry ``path``, or None when there is no readable, undamaged one."""
    with contextlib.suppress(*LOAD_ERRORS), np.load(path) as data:
        arrays = {name: data[name] for name in names}
        _used(path)
        return arrays
    return None


def _used(path: Path) -> None:
    """Set the entry's access time to now, keeping its modification time (which keys the memory cache):
    the eviction removes the entries read longest ago first, whatever the folder's mount does with reads."""
    try:
        os.utime(path, ns=(time.time_ns(), path.stat().st_mtime_ns))
    except PermissionError:     # another user's entry in a shared cache: only its owner may set the times
        with contextlib.suppress(OSError):
            os.utime(path)      # both: this process and others read it again, rather than build it
    except OSError:
        pass


def _entry_state(path: Path) -> tuple | None:
    """The entry's path, modification time and size (a replaced or damaged file is read again), or
    None when there is no readable entry."""
    try:
        stat = path.stat()
    except OSError:
        return None
    return str(path), stat.st_mtime_ns, stat.st_size


def _from_memory(path: Path) -> Model | None:
    """The model this process holds for the entry ``path``: while the entry is as it was read or stored,
    and where another process's eviction removed it (stored again, for the others); None where it was
    replaced (read it again) or is not held."""
    held = _in_memory.get(str(path))
    if held is None:
        return None
    state, model = held
    now = _entry_state(path)
    if now is None:
        _store(_model_arrays(model), path)
    elif now != state:
        return None
    return model


def _remember(key: tuple | None, model: Model, path: Path) -> None:
    if key is None:
        return
    for i, part in enumerate(model.parts):
        for array in (part.vertices, part.faces, part.component):
            array.flags.writeable = False
        if part.store is None:
            part.store = DerivedArrays(path.parent / "derived" / f"{path.stem}-part{i}")
    _in_memory[str(path)] = (key, model)
    _in_memory.move_to_end(str(path))
    while len(_in_memory) > MEMORY_ENTRIES:
        _in_memory.popitem(last=False)


def _copy(model: Model) -> Model:
    """A model of its own (name, lists, meta) over the same read-only arrays."""
    return dataclasses.replace(model, parts=list(model.parts), components=list(model.components),
                               meta=copy.deepcopy(model.meta))


class DerivedArrays:
    """What is computed from a cached part's mesh (:meth:`~.models.Part.of_mesh`: its proxy cells, face
    normals, triangle areas), kept in the folder ``derived`` beside the model's entry, one file for each
    function: ``STEM-FUNCTION-HASH.npz``, the hash that of the function's module source, so that editing
    the code that computes it makes a new file."""

    def __init__(self, stem: Path):
        self.stem = stem

    def get(self, compute) -> np.ndarray | None:
        """The array kept for ``compute``, or None (none yet, or an unreadable or damaged one, or a
        function without a name of its own in its module: a lambda, a closure)."""
        kept = _read(self._path(compute), ("value",)) if _named(compute) else None
        return None if kept is None else kept["value"]

    def put(self, compute, value: np.ndarray) -> None:
        """Keep ``value`` for ``compute`` (best effort, as the models)."""
        if _named(compute):
            _store({"value": value}, self._path(compute))

    def _path(self, compute) -> Path:
        return self.stem.with_name(f"{self.stem.name}-{compute.__qualname__}-{_source_hash(compute.__module__)}.npz")


def _named(compute) -> bool:
    """Whether ``compute`` has a name of its own in a module with a source file (not a lambda or closure)."""
    module = sys.modules.get(compute.__module__)
    return "<" not in compute.__qualname__ and getattr(module, "__file__", None) is not None


@functools.cache
def _source_hash(module: str) -> str:
    """A hash of ``module``'s source file (what decides the arrays its functions derive)."""
    return hashlib.sha256(Path(sys.modules[module].__file__).read_bytes()).hexdigest()[:12]


def _warn_write_failed(folder: Path, error: OSError) -> None:
    global _write_failed
    if not _write_failed:
        _write_failed = True
        log.warning("mitsuforest: cannot write the model cache in %s (%s); going on without it, so models "
                    "are built anew (set MITSUFOREST_CACHE to a writable folder to keep them)", folder, error)


def _model_arrays(model: Model) -> dict[str, np.ndarray]:
    """A model as the arrays of its entry: a JSON header, each part's vertices, faces and components, the
    hull's corners."""
    arrays = {}
    for i, p in enumerate(model.parts):
        arrays[f"v{i}"], arrays[f"f{i}"], arrays[f"c{i}"] = p.vertices, p.faces, p.component
    arrays["hull"] = model.hull_corners()
    header = {"name": model.name, "parts": [p.name for p in model.parts],
              "components": [[c.kind, c.classification] for c in model.components],
              "volume": model.volume.as_dict() if model.volume else None,
              "meta": model.meta}
    return {"header": np.array(json.dumps(header)), **arrays}


def _store(arrays: dict[str, np.ndarray], path: Path) -> None:
    """Write ``arrays`` to ``path`` (.npz) whole or not at all, so that a reader never sees a partial
    entry; a cache that cannot be written warns once (:func:`_warn_write_failed`)."""
    tmp = path.with_suffix(f".tmp-{os.getpid()}.npz")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    except OSError as e:
        _warn_write_failed(path.parent, e)
    else:
        _keep_within_limit(path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def _keep_within_limit(stored: Path) -> None:
    """After ``stored`` was written: where the cache, as this process last counted it plus what it stored
    since, is past :func:`cache_limit`, or its stores since pass :data:`RECOUNT` of the bound (other
    processes store too), count it again and, past the bound, evict (:func:`_evict`)."""
    try:
        limit = cache_limit()
    except UserError:       # refused up front by the commands; the API's caller keeps an unbounded cache
        return
    if limit is None:
        return
    root = cache_dir()
    counted, since = _cache_bytes.get(root, (None, 0))
    with contextlib.suppress(OSError):
        since += stored.stat().st_size
        if counted is not None and counted + since <= limit and since <= RECOUNT * limit:
            _cache_bytes[root] = (counted, since)
            return
        _cache_bytes[root] = (_evict(root, stored, limit), 0)


def _evict(root: Path, stored: Path, limit: int) -> int | None:
    """Count the cache under ``root`` and, past ``limit``, remove the entries read longest ago until it
    holds :data:`EVICT_TO` of it; returns the bytes left, or None where another process holds the
    eviction's lock (it evicts; this one counts again at its next store). An entry read since it was
    counted, and ``stored``, stay. A process reading an entry as it is removed keeps reading it on a local
    disk; on NFS, from another node, it reads it again or builds it."""
    with open(root / ".evict.lock", "a") as lock:
        if fcntl is not None:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return None
        entries = sorted(_entries(root))                  # (last read, size, path), longest ago first
        total = sum(e[1] for e in entries)
        if total <= limit:
            return total
        for read, size, path in entries:
            if total <= EVICT_TO * limit:
                break
            if path == stored:
                continue
            try:
                if path.stat().st_atime_ns > read:
                    continue
                path.unlink()
            except FileNotFoundError:                     # removed meanwhile: freed all the same
                pass
            except OSError:
                continue
            total -= size
        return total


def _entries(root: Path) -> list[tuple[int, int, Path]]:
    """(access time in ns, size, path) of every entry under ``root`` and ``root/derived``."""
    found = []
    for folder in (root, root / "derived"):
        with contextlib.suppress(OSError), os.scandir(folder) as it:
            for e in it:
                if e.is_file(follow_symlinks=False) and e.name.endswith(".npz") and ".tmp-" not in e.name:
                    with contextlib.suppress(OSError):
                        st = e.stat(follow_symlinks=False)
                        found.append((st.st_atime_ns, st.st_size, Path(e.path)))
    return found


def _load(path: Path) -> Model:
    with np.load(path) as data:
        h = json.loads(str(data["header"]))
        parts = [Part(name, data[f"v{i}"], data[f"f{i}"], data[f"c{i}"]) for i, name in enumerate(h["parts"])]
        hull = data["hull"] if "hull" in data.files else None
    _used(path)
    volume = WoodVolume(**h["volume"]) if h["volume"] else None
    return Model(h["name"], parts, [Component(k, c) for k, c in h["components"]], volume,
                 h["meta"], hull)
