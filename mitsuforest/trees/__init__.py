"""Stage 2: the meshes of every model a plan places, with components and wood volumes.

>>> models = build_models(plan)   # doctest: +SKIP   {model name: Model}
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np

from ..specs import ModelSpec
from ..specs.archetypes import DEFAULT_ARCHETYPES, Archetype
from ..specs.sources import MeshTree, QsmTree
from .cache import cached
from .imported import imported_model, summary as imported_summary
from .models import Component, Model, Part, tree_components, tree_model
from .skeleton import grow
from .ground_layer import grass_patch_model, litter_patch_model
from .understory import bush_model, deadwood_model, rock_model, stump_model

__all__ = ["Archetype", "DEFAULT_ARCHETYPES", "Model", "Part", "Component", "build_model", "build_models", "tree_shape"]

_BUILDERS = {"bush": bush_model, "rock": rock_model, "stump": stump_model, "deadwood": deadwood_model,
             "grass": grass_patch_model, "litter": litter_patch_model}


def tree_shape(source: Archetype | MeshTree | QsmTree) -> tuple[np.ndarray, int]:
    """What the plan needs of a tree model's shape (see :func:`mitsuforest.plan.plan_scene`): (k, 3) crown
    points in the model's frame, whose outline seen from above is the crown's cover, and the number of
    its labelled components (object ids per placed copy).

    An archetype's crown is its skeleton widened outward by a leaf length; an imported tree's, the
    corners of its model's hull (the model is built here, or read from the cache).
    """
    if isinstance(source, Archetype):
        return _archetype_shape(source)
    return imported_summary(source)


@lru_cache(maxsize=64)
def _archetype_shape(a: Archetype) -> tuple[np.ndarray, int]:
    """Cached per process: a dataset worker plans many plots of the same archetypes, and growing their
    skeletons was most of a small plot's planning time. The crown array is shared, so it is read-only."""
    branches = grow(a)
    pts = np.vstack([b.points for b in branches])
    radial = pts.copy()
    radial[:, 2] = 0
    norm = np.linalg.norm(radial, axis=1, keepdims=True)
    crown = pts + radial / np.maximum(norm, 1e-9) * a.leaf_length
    crown.flags.writeable = False
    return crown, len(tree_components(a, branches))


def build_model(name: str, spec: ModelSpec) -> Model:
    """One model from its plan entry (:class:`~mitsuforest.specs.ModelSpec`): a tree archetype or an
    understory kind with its seed (deadwood also its length and radius)."""
    if spec.kind == "tree" and spec.source is not None:
        return imported_model(spec.source, name)
    if spec.kind == "tree" and spec.drawn:   # used by one plot only: caching thousands would fill the disk
        model = tree_model(spec.archetype, name)
    elif spec.kind == "tree":
        archetype = spec.archetype
        params = {k: v for k, v in dataclasses.asdict(archetype).items() if k != "weight"}
        model = cached("tree", params, lambda: tree_model(archetype, name))
    else:
        params = spec.parameters()
        model = cached(spec.kind, params, lambda: _BUILDERS[spec.kind](name=name, **params))
    model.name = name
    return model


def build_models(plan, progress=None) -> dict[str, Model]:
    """Every model of the plan, from the cache where possible."""
    models = {}
    for name, spec in plan.models.items():
        models[name] = build_model(name, spec)
        if progress:
            progress(name)
    return models
