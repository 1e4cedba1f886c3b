"""What the stages share about the models to build: tree archetypes and their drawing
(:mod:`.archetypes`), imported tree sources (:mod:`.sources`) and :class:`ModelSpec`, a plan's order for
one model. Config reads them from scene files, the plan writes them, the trees stage builds them; this
package imports no stage.
"""

from __future__ import annotations

from dataclasses import dataclass

from .archetypes import Archetype
from .sources import MeshTree, QsmTree

__all__ = ["ModelSpec", "Archetype", "MeshTree", "QsmTree"]


@dataclass(frozen=True)
class ModelSpec:
    """What to build for one model: a tree archetype, or an understory kind and its parameters."""

    kind: str                            # tree, bush, rock, deadwood, stump, grass, litter (or custom, in tests)
    components: int                      # labelled components (object ids per placed copy)
    archetype: Archetype | None = None   # procedural trees
    drawn: bool | None = None            # a unique tree (forest.archetypes unique: N): one plot's own, not cached on disk
    source: MeshTree | QsmTree | None = None   # imported trees (forest.models)
    seed: int | None = None              # understory
    length: float | None = None          # deadwood
    radius: float | None = None
    form: int | None = None              # bush: index into understory.SHRUB_FORMS
    height: float | None = None          # grass: mean blade length (trees/ground_layer.py)

    @property
    def species(self) -> str:
        """The species name (classes.SPECIES_CODES): a procedural tree's family, ``none`` for everything else."""
        return self.archetype.species if self.kind == "tree" and self.archetype is not None else "none"

    def parameters(self) -> dict:
        """The understory builder's keyword arguments (seed, a log's length and radius, a shrub's form, a
        grass patch's blade height)."""
        return {k: getattr(self, k) for k in ("seed", "length", "radius", "form", "height") if getattr(self, k) is not None}
