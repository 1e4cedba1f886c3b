"""What the plan orders of the understory and the ground layer: the shrub forms, the labelled
components of an understory model, and the ground layer's patch size and models per kind."""

from __future__ import annotations

from dataclasses import dataclass

UNDERSTORY_COMPONENTS = 1   # every understory model is one labelled component
UNDERSTORY_KEYS = {"bush": "bushes", "rock": "rocks", "deadwood": "deadwood", "stump": "stumps"}  # understory.KEY
# m: the clear disc (a log's corridor) each understory object keeps from stems and from the others. Logs:
# side branches reach 1.3 m, bow 0.1 m; stump roots 0.9 m.
CLEARANCE = {"bush": 1.7, "rock": 1.0, "stump": 1.0, "deadwood": 1.5}
PATCH_SIZE = 1.0            # m, side of a ground layer patch (and of a plan cell)
PATCH_MODELS = 4            # distinct ground layer models of each kind (grass, litter) whatever the cover


@dataclass(frozen=True)
class ShrubForm:
    """One shrub archetype: ranges drawn per model from its seed (lengths m, angles degrees)."""

    height: tuple[float, float]
    crown: tuple[float, float]         # crown diameter: the stems and shoots are spread to it
    stems: tuple[int, int]             # stems from the root collar
    spread: float                      # largest stem angle from vertical
    shoots: int                        # side shoots per stem
    shoot_angle: float                 # side shoot angle from its stem
    leaf_length: float
    leaf_width: float
    leaf_area_density: float           # one-sided leaf area per m3 of the shrub's envelope (m2/m3)
    leaf_inclination: float


# Heath (dense, low, many fine stems), an upright tea-tree-like shrub, a spreading wattle-like shrub and an
# open, tall sapling-like shrub: different sizes and densities, so bushes do not all look alike. Heights
# and crowns span the shrub layers of Australian eucalypt woodland and open forest, 0.5-3 m tall and
# 0.5-3 m across (README, "Understory", gives the sources).
SHRUB_FORMS: tuple[ShrubForm, ...] = (
    ShrubForm(height=(0.5, 0.9), crown=(0.6, 1.2), stems=(9, 14), spread=40, shoots=3, shoot_angle=40,
              leaf_length=0.025, leaf_width=0.008, leaf_area_density=3.0, leaf_inclination=30),
    ShrubForm(height=(1.5, 2.5), crown=(1.0, 1.8), stems=(3, 5), spread=15, shoots=5, shoot_angle=35,
              leaf_length=0.04, leaf_width=0.01, leaf_area_density=1.6, leaf_inclination=45),
    ShrubForm(height=(1.0, 1.8), crown=(1.8, 3.0), stems=(5, 8), spread=55, shoots=4, shoot_angle=50,
              leaf_length=0.07, leaf_width=0.012, leaf_area_density=1.2, leaf_inclination=40),
    ShrubForm(height=(2.2, 3.0), crown=(1.5, 2.5), stems=(2, 3), spread=10, shoots=6, shoot_angle=55,
              leaf_length=0.08, leaf_width=0.025, leaf_area_density=0.5, leaf_inclination=55),
)
