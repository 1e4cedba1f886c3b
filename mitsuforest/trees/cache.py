"""Disk cache of models, keyed by a hash of their parameters and the geometry code version.

Location: ``$MITSUFOREST_CACHE`` or ``~/.cache/mitsuforest``. Delete the folder to clear it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .models import Component, Model, Part
from .volume import WoodVolume

GEOMETRY_VERSION = 4  # bump when a change to the generators changes any mesh


def cache_dir() -> Path:
    return Path(os.environ.get("MITSUFOREST_CACHE", Path.home() / ".cache" / "mitsuforest")) / "models"


def cache_key(kind: str, params: dict) -> str:
    text = json.dumps({"kind": kind, "params": params, "version": GEOMETRY_VERSION}, sort_keys=True)
    return f"{kind}-{hashlib.sha256(text.encode()).hexdigest()[:20]}"


def cached(kind: str, params: dict, build) -> Model:
    """Load the model for ``(kind, params)`` from the cache, or ``build()`` it and store it."""
    path = cache_dir() / (cache_key(kind, params) + ".npz")
    if path.exists():
        try:
            return _load(path)
        except (OSError, ValueError, KeyError):
            pass  # a damaged entry is rebuilt
    model = build()
    _save(model, path)
    return model


def _save(model: Model, path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for i, p in enumerate(model.parts):
        arrays[f"v{i}"], arrays[f"f{i}"], arrays[f"c{i}"] = p.vertices, p.faces, p.component
    header = {"name": model.name, "parts": [p.name for p in model.parts],
              "components": [[c.kind, c.classification] for c in model.components],
              "volume": model.volume.as_dict() if model.volume else None,
              "meta": model.meta}
    tmp = path.with_suffix(f".tmp-{os.getpid()}.npz")
    np.savez(tmp, header=np.array(json.dumps(header)), **arrays)
    os.replace(tmp, path)


def _load(path: Path) -> Model:
    with np.load(path) as data:
        h = json.loads(str(data["header"]))
        parts = [Part(name, data[f"v{i}"], data[f"f{i}"], data[f"c{i}"]) for i, name in enumerate(h["parts"])]
    volume = WoodVolume(**h["volume"]) if h["volume"] else None
    return Model(h["name"], parts, [Component(k, c) for k, c in h["components"]], volume,
                 h["meta"])
