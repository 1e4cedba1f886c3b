"""Sections of a render's manifest that describe its models (the rest is :mod:`mitsuforest.survey`'s)."""

from __future__ import annotations

from .atomic import finite_or_null


def import_report(plan, models: dict) -> dict:
    """Per imported tree model of a plan: its file, height, volumes and the repair of each changed part
    (for the run manifest). A volume that is not defined (a mesh's cylinder sum, an open part's volume)
    is None, JSON's null, not nan."""
    out = {}
    for name, spec in plan.models.items():
        if getattr(spec, "source", None) is not None and name in models:
            model = models[name]
            out[name] = {"source": spec.source.source, "height_m": model.meta.get("height"),
                         "volume_m3": finite_or_null(model.volume.as_dict()), "triangles": model.triangles,
                         "parts_ok": model.meta.get("parts_ok"),
                         "repair": finite_or_null(model.meta.get("repair", []))}
    return out
