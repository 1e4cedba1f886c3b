"""Stage 2: the meshes of every model a plan places, with components and wood volumes.

>>> models = build_models(plan)   # doctest: +SKIP   {model name: Model}
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from ..specs import ModelSpec
from ..specs.archetypes import DEFAULT_ARCHETYPES, Archetype
from ..specs.sources import MeshTree, QsmTree
from .cache import cached, cached_arrays, is_stored
from .imported import imported_model, summary as imported_summary
from .models import Component, Model, Part, tree_components, tree_model
from .parallel import in_workers
from .skeleton import grow
from .ground_layer import grass_patch_model, litter_patch_model
from .understory import bush_model, deadwood_model, rock_model, stump_model

__all__ = ["Archetype", "DEFAULT_ARCHETYPES", "Model", "Part", "Component", "build_model", "build_models", "tree_shape",
           "tree_shapes"]

_BUILDERS = {"bush": bush_model, "rock": rock_model, "stump": stump_model, "deadwood": deadwood_model,
             "grass": grass_patch_model, "litter": litter_patch_model}


def tree_shape(source: Archetype | MeshTree | QsmTree, keep: bool = True) -> tuple[np.ndarray, int]:
    """What the plan needs of a tree model's shape (see :func:`mitsuforest.plan.plan_scene`): (k, 3) crown
    points in the model's frame, whose outline seen from above is the crown's cover, and the number of
    its labelled components (object ids per placed copy).

    An archetype's crown is its skeleton widened outward by a leaf length, kept in the model cache
    unless ``keep`` is false (a plot's drawn unique trees, whose models are not kept either); an
    imported tree's, the corners of its model's hull (the model is built here, or read from the cache).
    """
    if isinstance(source, Archetype):
        return _archetype_shape(source, keep)
    return imported_summary(source)


def tree_shapes(sources: Sequence[Archetype | MeshTree | QsmTree], keep: bool | Sequence[bool] = True,
                progress=None) -> list[tuple[np.ndarray, int]]:
    """:func:`tree_shape` of each of ``sources``, in order (``keep`` for all, or one for each): the
    archetypes' crowns that the cache does not hold grown in worker processes where there are many
    (:mod:`.parallel`). ``progress``, when given, is called once a shape is had."""
    sources = list(sources)
    keeps = [keep] * len(sources) if isinstance(keep, bool) else list(keep)
    todo = [i for i, (s, k) in enumerate(zip(sources, keeps)) if isinstance(s, Archetype) and not (k and _crown_stored(s))]
    grown = in_workers(_archetype_shape, [(sources[i], keeps[i]) for i in todo])
    todo = set(todo)
    out = []
    for i, (source, k) in enumerate(zip(sources, keeps)):
        ok, shape = next(grown) if i in todo else (False, None)
        if ok:
            shape[0].flags.writeable = False
        out.append(shape if ok else tree_shape(source, k))
        if progress:
            progress()
    return out


def _crown_stored(a: Archetype) -> bool:
    return is_stored("crown", archetype_parameters(a))


@lru_cache(maxsize=64)
def _archetype_shape(a: Archetype, keep: bool) -> tuple[np.ndarray, int]:
    """Cached per process, and on disk when ``keep``: growing an archetype's skeleton took 0.05-0.1 CPU s,
    most of a small plot's planning (0.8 s for the demo's ten in a fresh process). The crown array is
    shared, so it is read-only."""
    names = ("crown", "components")
    if keep:
        shape = cached_arrays("crown", archetype_parameters(a), names, lambda: _grown_crown(a))
    else:
        shape = _grown_crown(a)
    crown = shape["crown"]
    crown.flags.writeable = False
    return crown, int(shape["components"])


def _grown_crown(a: Archetype) -> dict[str, np.ndarray]:
    branches = grow(a)
    pts = np.vstack([b.points for b in branches])
    radial = pts.copy()
    radial[:, 2] = 0
    norm = np.linalg.norm(radial, axis=1, keepdims=True)
    crown = pts + radial / np.maximum(norm, 1e-9) * a.leaf_length
    return {"crown": crown, "components": np.array(len(tree_components(a, branches)))}


def archetype_parameters(a: Archetype) -> dict:
    """An archetype's fields that decide its geometry (all but its weight in a mix): its cache key's."""
    return {k: v for k, v in dataclasses.asdict(a).items() if k != "weight"}


def build_model(name: str, spec: ModelSpec) -> Model:
    """One model from its plan entry (:class:`~mitsuforest.specs.ModelSpec`): a tree archetype or an
    understory kind with its seed (deadwood also its length and radius)."""
    if spec.kind == "tree" and spec.source is not None:
        return imported_model(spec.source, name)
    if spec.kind == "tree" and spec.drawn:   # used by one plot only: caching thousands would fill the disk
        model = tree_model(spec.archetype, name)
    elif spec.kind == "tree":
        archetype = spec.archetype
        model = cached("tree", archetype_parameters(archetype), lambda: tree_model(archetype, name))
    else:
        params = spec.parameters()
        model = cached(spec.kind, params, lambda: _BUILDERS[spec.kind](name=name, **params))
    model.name = name
    return model


def build_models(plan, progress=None, order=None) -> dict[str, Model]:
    """Every model of the plan, from the cache where possible, in the plan's order; the procedural models
    the cache does not hold built in worker processes where there are many (:mod:`.parallel`).

    :param order: the order in which to build or read them (a permutation of the plan's model rows; the
        plan's own by default): processes setting up one plot at once (a dataset's leg tasks) each take
        another, so that with a shared cache each builds a share and reads what the others stored.
    """
    names = list(plan.models)
    rows = list(range(len(names)) if order is None else order)
    todo = [names[row] for row in rows if _not_stored(plan.models[names[row]])]
    from_workers = in_workers(_built_in_worker, [(name, plan.models[name]) for name in todo])
    todo = set(todo)
    built = {}
    for row in rows:
        name = names[row]
        ok, model = next(from_workers) if name in todo else (False, None)
        built[name] = model if ok and model is not None else build_model(name, plan.models[name])
        if progress:
            progress(name)
    return {name: built[name] for name in names}


def _not_stored(spec: ModelSpec) -> bool:
    """Whether ``spec`` is a procedural model the cache does not hold (an imported one is built apart)."""
    if spec.kind == "tree":
        return spec.source is None and (spec.drawn or not is_stored("tree", archetype_parameters(spec.archetype)))
    return spec.kind in _BUILDERS and not is_stored(spec.kind, spec.parameters())


def _built_in_worker(name: str, spec: ModelSpec) -> Model | None:
    """A worker's job: build the model, and hand it back only where the cache does not now hold it (a
    drawn tree, or a cache that cannot be written); else the plan's process reads the entry."""
    model = build_model(name, spec)
    return model if _not_stored(spec) else None
