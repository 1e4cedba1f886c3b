"""Reading ``forest.trees_file``: a table of trees to place one by one (I/O only).

A CSV file with a header; columns ``x``, ``y`` (in the frame of ``origin``: the local frame plus
``origin.offset``, as a DEM's), ``height`` and ``crown_radius`` (m), and optionally ``species`` (one of
the procedural families; by default the scene's), ``leaf_area`` (m², one-sided; by default the
template's, in proportion to the crown volume) and ``crown_ratio`` (live crown length over height; by
default the template's). An empty cell takes the default. Each refusal is a
:class:`~mitsuforest.errors.UserError` whose text the plan reports as ``FILE: forest.trees_file: reason``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

from ..classes import TREE_SPECIES
from ..errors import UserError
from ..specs.archetypes import FIELDS
from ..textfiles import SEMICOLONS, NotTextError, read_text, repeated, semicolon_separated

COLUMNS = ("x", "y", "height", "crown_radius")
CROWN_RATIO = (FIELDS["crown_ratio"].metadata["lo"], FIELDS["crown_ratio"].metadata["hi"])
MAX_HEIGHT = FIELDS["height"].metadata["hi"]   # m: the procedural trees grow no taller (shorter ones are raised)
MAX_LEAF_AREA = FIELDS["leaf_area"].metadata["hi"]   # m², one-sided: the most a procedural tree carries


@dataclass(frozen=True)
class ListedTree:
    """One row of a tree list, in the local frame."""

    x: float
    y: float
    height: float
    crown_radius: float
    species: str | None
    leaf_area: float | None = None
    crown_ratio: float | None = None


def read_tree_list(path, offset=(0.0, 0.0, 0.0)) -> list[ListedTree]:
    """The trees of a tree-list CSV, moved into the local frame (``origin.offset`` subtracted)."""
    try:
        rows = list(csv.reader(io.StringIO(read_text(path), newline="")))
    except (OSError, NotTextError) as e:
        raise UserError(f"cannot read the tree list {path}: {e}") from None
    except csv.Error as e:   # a cell over 128 kB (a quote left open, a binary file)
        raise UserError(f"{path}: not a CSV tree list ({e})") from None
    if not rows:
        raise UserError(f"{path}: the tree list is empty (it needs a header {','.join(COLUMNS)})")
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing and semicolon_separated(header):
        raise UserError(f"{path}: the tree list is {SEMICOLONS}")
    if missing:
        raise UserError(f"{path}: the tree list lacks the column(s) {', '.join(missing)} (header: {','.join(header)[:200]!r})")
    read = (*COLUMNS, "species", "leaf_area", "crown_ratio")
    if twice := repeated(header, read):
        raise UserError(f"{path}: the tree list has the column {twice} {header.count(twice)} times; keep one")
    at = {c: header.index(c) for c in read if c in header}
    out = []
    for line, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        if len(row) < len(header):
            raise UserError(f"{path}: line {line}: {len(row)} cells, the header has {len(header)}")
        if any(cell.strip() for cell in row[len(header):]):   # empty ones are a spreadsheet's trailing commas
            raise UserError(f"{path}: line {line}: {len(row)} cells, the header has {len(header)} (a decimal comma, "
                            "as in 12,5, splits a number in two cells: write 12.5)")
        values = {c: _number(row[at[c]], path, line, c) for c in COLUMNS}
        if values["height"] <= 0 or values["crown_radius"] <= 0:
            raise UserError(f"{path}: line {line}: height and crown_radius must be > 0")
        if values["height"] > MAX_HEIGHT:   # was grown to MAX_HEIGHT: a list in cm or feet made a stand of 80 m trees
            raise UserError(f"{path}: line {line}: height {values['height']:,g} m is taller than the procedural trees "
                            f"grow (at most {MAX_HEIGHT:g} m); the list is in metres")
        species = row[at["species"]].strip() if "species" in at else ""
        if species and species not in TREE_SPECIES:
            raise UserError(f"{path}: line {line}: species must be one of {', '.join(TREE_SPECIES)}, got {species!r}")
        leaf_area = None
        if "leaf_area" in at and row[at["leaf_area"]].strip():
            leaf_area = _number(row[at["leaf_area"]], path, line, "leaf_area")
            if leaf_area < 0:
                raise UserError(f"{path}: line {line}: leaf_area must be >= 0")
            if leaf_area > MAX_LEAF_AREA:   # was cut to MAX_LEAF_AREA without a word
                raise UserError(f"{path}: line {line}: leaf_area {leaf_area:,g} m² is more than a procedural tree "
                                f"carries (at most {MAX_LEAF_AREA:,g} m²)")
        crown_ratio = None
        if "crown_ratio" in at and row[at["crown_ratio"]].strip():
            crown_ratio = _number(row[at["crown_ratio"]], path, line, "crown_ratio")
            if not CROWN_RATIO[0] <= crown_ratio <= CROWN_RATIO[1]:
                raise UserError(f"{path}: line {line}: crown_ratio must be within {CROWN_RATIO[0]:g}-{CROWN_RATIO[1]:g}, "
                                f"got {crown_ratio:g}")
        out.append(ListedTree(values["x"] - offset[0], values["y"] - offset[1], values["height"],
                              values["crown_radius"], species or None, leaf_area, crown_ratio))
    return out


def _number(cell: str, path, line: int, column: str) -> float:
    try:
        value = float(cell)
    except ValueError:
        raise UserError(f"{path}: line {line}: {column} must be a number, got {cell!r}") from None
    if not math.isfinite(value):
        raise UserError(f"{path}: line {line}: {column} must be finite, got {cell!r}")
    return value
