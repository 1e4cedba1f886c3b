"""Point classes and tree ids shared by every stage (Synthetic Forest paper's codes)."""

GROUND, TREE_WOOD, TREE_LEAVES, DEADWOOD, ROCK, STUMP, BUSH = 1, 2, 3, 4, 5, 6, 7
GROUND_VEGETATION = 8   # the ground layer: grass tufts and leaf litter (understory.grass, understory.litter)

CLASS_NAMES = {GROUND: "ground", TREE_WOOD: "tree_wood", TREE_LEAVES: "tree_leaves", DEADWOOD: "deadwood",
               ROCK: "rock", STUMP: "stump", BUSH: "bush",
               GROUND_VEGETATION: "ground_vegetation"}


def class_name(code: int) -> str:
    """A class code's name (CLASS_NAMES), or ``class N`` for a code without one."""
    return CLASS_NAMES.get(int(code), f"class {int(code)}")

DEADWOOD_TREEID = 11   # treeid of deadwood points (one past the last tree model when there are more than ten);
                       # trees carry their model number: archetypes 1.., then forest.models; others 0
GROUND_OBJECT_ID = 1   # object ids start at 1 with the ground; 0 never labels a point

# Per-point ``species`` codes (PCD field and LAS extra dimension): the tree's procedural family;
# 0 on the ground, understory and deadwood.
SPECIES_CODES = {"none": 0, "eucalyptus": 1, "acacia": 2, "pinus_radiata": 3}
TREE_SPECIES = tuple(name for name in SPECIES_CODES if name != "none")
