"""Stage 2: the meshes of every model a plan places, with components and wood volumes.

>>> models = build_models(plan)   # doctest: +SKIP   {model name: Model}
"""

from __future__ import annotations

import dataclasses

from .archetypes import DEFAULT_ARCHETYPES, Archetype
from .cache import cached
from .models import Component, Model, Part, tree_model
from .understory import bush_model, deadwood_model, rock_model, stump_model

__all__ = ["Archetype", "DEFAULT_ARCHETYPES", "Model", "Part", "Component", "build_model", "build_models"]

_BUILDERS = {"bush": bush_model, "rock": rock_model, "stump": stump_model, "deadwood": deadwood_model}


def build_model(spec: dict) -> Model:
    """One model from its plan entry: ``{"kind": "tree", "archetype": {...}}`` or ``{"kind": k, "seed": s, ...}``
    (deadwood also takes ``length`` and ``radius``)."""
    kind, name = spec["kind"], spec["name"]
    if kind == "tree":
        archetype = Archetype(**spec["archetype"])
        params = {k: v for k, v in dataclasses.asdict(archetype).items() if k != "weight"}
        model = cached("tree", params, lambda: tree_model(archetype, name))
    else:
        params = {k: v for k, v in spec.items() if k not in ("kind", "name", "components")}
        model = cached(kind, params, lambda: _BUILDERS[kind](name=name, **params))
    model.name = name
    return model


def build_models(plan: dict, progress=None) -> dict[str, Model]:
    """Every model of the plan, from the cache where possible."""
    models = {}
    for name, spec in plan["models"].items():
        models[name] = build_model({**spec, "name": name})
        if progress:
            progress(name)
    return models
