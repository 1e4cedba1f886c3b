"""Stage 2: the meshes of every model a plan places, with components and wood volumes.

>>> models = build_models(plan)   # doctest: +SKIP   {model name: Model}
"""

from __future__ import annotations

import dataclasses

from ..specs.archetypes import DEFAULT_ARCHETYPES, Archetype
from .cache import cached
from .imported import imported_model
from .models import Component, Model, Part, tree_model
from .ground_layer import grass_patch_model, litter_patch_model
from .understory import bush_model, deadwood_model, rock_model, stump_model

__all__ = ["Archetype", "DEFAULT_ARCHETYPES", "Model", "Part", "Component", "build_model", "build_models"]

_BUILDERS = {"bush": bush_model, "rock": rock_model, "stump": stump_model, "deadwood": deadwood_model,
             "grass": grass_patch_model, "litter": litter_patch_model}


def build_model(name: str, spec) -> Model:
    """One model from its plan entry (:class:`~mitsuforest.plan.types.ModelSpec`): a tree archetype or an
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
