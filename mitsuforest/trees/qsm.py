"""Quantitative structure models (QSMs): cylinder tables of real trees (TreeQSM, AdQSM, SimpleForest).

A table has one cylinder a line and a header naming its columns; CSV (commas) or whitespace- or
tab-separated text. Column names are matched without case, spaces, underscores or a unit suffix
such as ``(m)``; a suffix naming a length unit, ``(m)``, ``(cm)``, ``(mm)`` or ``[cm]`` ..., is that
column's unit (a vector cell's, its three columns'), and the entry's ``units`` that of the columns naming none:

=============  ============================================================  ========
quantity       accepted names                                                needed
=============  ============================================================  ========
radius         radius, rad, r                                                yes
start x y z    start_x.., startpoint_x.., sx.., x_start..; or ``start_point``   yes
               / ``start`` followed by two blank header cells (TreeQSM)
axis x y z     axis_x.., axisdirection_x.., ax..; or ``axis_direction``       axis and
               / ``axis`` followed by two blank cells                          length, or
length         length, len, l                                                 end
end x y z      end_x.., endpoint_x.., ex.., x_end..                           (see left)
id             id, cylinder, cylinderid, cyl                                  no: 1.. by line
parent         parent, parentid, parentcylinder                               no
branch         branch, branchid, branchindex                                  no
branch order   branchorder, order, bo                                         no
=============  ============================================================  ========

A table without a header is read as TreeQSM's cylinder export (radius, length, start x y z, axis
x y z, parent, extension, branch, branch order, ...: at least 12 numeric columns). ``parent`` refers
to ``id`` (TreeQSM: the 1-based line number; 0 for the stem base). Object ids are given per branch;
without a branch column the whole wood is one component.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..specs.sources import UNITS, ModelFileError
from ..textfiles import SEMICOLONS, NotTextError, read_text, semicolon_separated

ALIASES = {
    "radius": ("radius", "rad", "r"),
    "length": ("length", "len", "l"),
    "id": ("id", "cylinder", "cylinderid", "cyl", "cylid"),
    "parent": ("parent", "parentid", "parentcylinder"),
    "branch": ("branch", "branchid", "branchindex"),
    "order": ("branchorder", "order", "bo"),
}
VECTORS = {   # quantity: (names of the vector header cell, prefixes and suffixes of its x y z columns)
    "start": (("startpoint", "start", "sta"), ("start", "startpoint", "s", "sta"), ("start", "s")),
    "axis": (("axisdirection", "axis", "axe", "direction"), ("axis", "axisdirection", "a", "dir", "axe"), ("axis",)),
    "end": (("endpoint", "end"), ("end", "endpoint", "e"), ("end", "e")),
}
QUANTITIES = set(ALIASES) | {f"{q}_{a}" for q in VECTORS for a in "xyz"}   # the columns read
TREEQSM_COLUMNS = ["radius", "length", "start_x", "start_y", "start_z", "axis_x", "axis_y", "axis_z", "parent",
                   "extension", "branch", "order"]


@dataclass
class Cylinders:
    """A QSM's cylinders, in the table's order.

    ``start``, ``end``: (n, 3) float64; ``radius``: (n,); ``parent``: (n,) row of the parent
    cylinder, -1 for none; ``branch``: (n,) int64 branch ids (all 0 without a branch column);
    ``order``: (n,) branch order (0 stem); ``line``: (n,) each cylinder's line in the file (from 1).
    """

    start: np.ndarray
    end: np.ndarray
    radius: np.ndarray
    parent: np.ndarray
    branch: np.ndarray
    order: np.ndarray
    line: np.ndarray

    @property
    def length(self) -> np.ndarray:
        return np.linalg.norm(self.end - self.start, axis=1)

    def volume(self) -> float:
        """The QSM's own volume: the sum of its cylinders, ``Σ π r² L`` (joints counted twice)."""
        return float(np.sum(np.pi * self.radius ** 2 * self.length))

    def branch_lines(self) -> dict[int, np.ndarray]:
        """Each branch's centreline (k+1, 3): its cylinders' starts in table order and the last end."""
        lines = {}
        for b in np.unique(self.branch):
            rows = np.flatnonzero(self.branch == b)
            lines[int(b)] = np.vstack([self.start[rows], self.end[rows[-1:]]])
        return lines

    def terminal_branches(self) -> list[int]:
        """Branches no other branch grows from (the twigs that carry leaves); every branch without
        parents. Without a branch column: the cylinders no cylinder grows from, each as a branch."""
        has_child = np.zeros(len(self.radius), bool)
        has_child[self.parent[self.parent >= 0]] = True
        if np.all(self.branch == self.branch[0]) and len(self.radius) > 1:
            return [int(i) for i in np.flatnonzero(~has_child)]
        parent_branch = np.full(len(self.radius), -1)
        ok = self.parent >= 0
        parent_branch[ok] = self.branch[self.parent[ok]]
        grown_from = set(parent_branch[ok & (parent_branch != self.branch)].tolist())
        return [int(b) for b in np.unique(self.branch) if int(b) not in grown_from]


def _key(name: str) -> str:
    name = re.sub(r"\(.*?\)|\[.*?\]", "", name.lower())
    return re.sub(r"[^a-z0-9]", "", name)


def _column_names(cells: list[str]) -> tuple[list[str], list[str | None]]:
    """Header cells as quantity names (``radius``, ``start_x`` ...) and each column's unit (``m``, ``cm``,
    ``mm``, or None where the cell names none); a vector cell (``start_point``) becomes three columns,
    taking the two blank cells after it where the header has them (TreeQSM's tabs)."""
    keys = [_key(c) for c in cells]
    out, units, i = [], [], 0
    while i < len(keys):
        k = keys[i]
        vector = next((q for q, (names, _, _) in VECTORS.items() if k in names), None)
        if vector:
            out += [f"{vector}_{a}" for a in "xyz"]
            units += [_unit(cells[i])] * 3
            i += 3 if keys[i + 1:i + 3] == ["", ""] else 1
            continue
        out.append(_component(k) or next((q for q, names in ALIASES.items() if k in names), k))
        units.append(_unit(cells[i]))
        i += 1
    return out, units


def _unit(cell: str) -> str | None:
    """The length unit a header cell names in brackets, ``radius (cm)`` or ``StartX [mm]``; else None."""
    found = re.search(r"[(\[]\s*(mm|cm|m)\s*[)\]]", cell.lower())
    return found.group(1) if found else None


def _component(k: str) -> str | None:
    for quantity, (_, prefixes, suffixes) in VECTORS.items():
        for a in "xyz":
            if k in {p + a for p in prefixes} | {a + s for s in suffixes}:
                return f"{quantity}_{a}"
    return None


def read_qsm(path, units: str = "m") -> Cylinders:
    """Read a cylinder table (see module docstring), in metres.

    :param units: ``m``, ``cm`` or ``mm``: the unit of the lengths and coordinates of the columns whose
        header names none (all of them in a table without a header).
    :raises ModelFileError: on missing columns, text in number columns, non-positive radii or lengths.
    """
    lines = _table_lines(path)
    first = lines[0][1]
    sep = "," if "," in first else ("\t" if "\t" in first else None)
    header = [c.strip() for c in first.split(sep)]
    if semicolon_separated(header):
        raise ModelFileError(path, "", f"the cylinder table is {SEMICOLONS}")
    if all(_number(c) for c in header if c):
        if len([c for c in header if c]) < len(TREEQSM_COLUMNS):
            raise ModelFileError(path, "", "no header line, and fewer than the 12 columns of TreeQSM's cylinder "
                                 "export; add a header naming the columns (see the README)")
        columns, rows, exact = TREEQSM_COLUMNS, lines, False   # TreeQSM's export has more columns after these
        column_units = [None] * len(columns)
    else:
        (columns, column_units), rows, exact = _column_names(header), lines[1:], True
    table = _numbers(path, rows, sep, len(columns), exact)
    _check_units(path, columns, column_units, units)
    named = {}
    for i, c in enumerate(columns):
        if c in named and c in QUANTITIES:
            raise ModelFileError(path, "", f"columns {columns.index(c) + 1} and {i + 1} both give {c}; keep one")
        if c:   # lengths and coordinates in metres; an axis is a direction, and ids have no unit
            named[c] = table[:, i] * UNITS[column_units[i] or units] if c in LENGTHS else table[:, i]
    return _cylinders(path, named, np.array([n for n, _ in rows]))


def _check_units(path, columns: list[str], column_units: list[str | None], units: str) -> None:
    """Refuse ``units`` cm or mm where the header names another unit for a length column: one of the two is
    wrong (TreeQSM names metres on its radius and length, not on its start point, which units would scale)."""
    if units == "m":
        return
    other = [f"{c} in {u}" for c, u in zip(columns, column_units) if c in LENGTHS and u and u != units]
    if other:
        raise ModelFileError(path, "units", f"the header gives {', '.join(dict.fromkeys(other))}, but units: {units}; "
                             "a column whose header names its unit is read in it, and units is the unit of the "
                             "others: drop units, or the header's unit")


def _table_lines(path) -> list[tuple[int, str]]:
    """(line number from 1, text) of the lines that are neither blank nor comments."""
    try:
        text = read_text(path)
    except NotTextError:
        raise ModelFileError(path, "", "not a text table (a binary file; TreeQSM's .mat models must be exported "
                             "as a text cylinder table first)") from None
    except OSError as e:
        raise ModelFileError(path, "", f"cannot read the cylinder table ({e})") from None
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ModelFileError(path, "", "the cylinder table is empty")
    return lines


def _number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _numbers(path, rows, sep, width, exact) -> np.ndarray:
    """(len(rows), width) the table's numbers; with ``exact`` a row must have ``width`` values, else at least."""
    if not rows:
        raise ModelFileError(path, "", "no cylinders after the header")
    out = np.empty((len(rows), width))
    for i, (n, row) in enumerate(rows):
        cells = [c.strip() for c in row.split(sep)]
        cells = [c for c in cells if c] if sep != "," else cells
        if len(cells) < width or (exact and len(cells) > width):
            raise ModelFileError(path, f"line {n}", f"{len(cells)} values, the header names {width} columns")
        try:
            out[i] = [float(c) for c in cells[:width]]
        except ValueError:
            raise ModelFileError(path, f"line {n}", f"not a number in {row.strip()[:60]!r}") from None
    if not np.all(np.isfinite(out)):
        n = rows[int(np.flatnonzero(~np.all(np.isfinite(out), axis=1))[0])][0]
        raise ModelFileError(path, f"line {n}", "a value is not finite")
    return out


MAX_VALUE = 1e9   # as origin.offset: beyond every projected CRS
GEOMETRY = {"radius", "length", *(f"{p}_{a}" for p in ("start", "end", "axis") for a in "xyz")}
LENGTHS = GEOMETRY - {f"axis_{a}" for a in "xyz"}   # the columns a unit scales


def _cylinders(path, col: dict, line: np.ndarray) -> Cylinders:
    def need(*names):
        missing = [n for n in names if n not in col]
        if missing:
            raise ModelFileError(path, "", f"no {', '.join(missing)} column (columns: {', '.join(c for c in col if c)}); "
                                 "a QSM needs radius, start x y z, and axis x y z with length or end x y z")
        return [col[n] for n in names]

    for name, values in col.items():   # 1e308 overflowed the lengths and sums below, with numpy's warnings
        if name in GEOMETRY and np.any(np.abs(values) > MAX_VALUE):
            i = int(np.argmax(np.abs(values) > MAX_VALUE))
            raise ModelFileError(path, f"line {line[i]}", f"{name} {values[i]:g} is beyond ±{MAX_VALUE:g}: no tree's "
                                 "size or coordinate (even in millimetres on a map grid)")
    (radius,) = need("radius")
    start = np.column_stack(need("start_x", "start_y", "start_z"))
    if all(f"end_{a}" in col for a in "xyz"):
        end = np.column_stack(need("end_x", "end_y", "end_z"))
    else:
        axis = np.column_stack(need("axis_x", "axis_y", "axis_z"))
        (length,) = need("length")
        norm = np.linalg.norm(axis, axis=1)
        _positive(path, "length", length, line)   # a negative length would silently turn the axis round
        if np.any(norm == 0):
            raise ModelFileError(path, f"line {line[int(np.argmax(norm == 0))]}", "the axis is zero")
        end = start + axis / norm[:, None] * length[:, None]
    _positive(path, "radius", radius, line)
    _positive(path, "length", np.linalg.norm(end - start, axis=1), line)
    return Cylinders(start, end, radius, _parent_rows(path, col, line),
                     _whole(path, "branch", col.get("branch", np.zeros(len(radius))), line),
                     _whole(path, "branch order", col.get("order", np.zeros(len(radius))), line), line)


def _positive(path, name: str, values: np.ndarray, line: np.ndarray) -> None:
    bad = np.flatnonzero(~(values > 0))
    if len(bad):
        more = f" ({len(bad) - 1:,} more cylinders like it)" if len(bad) > 1 else ""
        raise ModelFileError(path, f"line {line[bad[0]]}", f"{name} {values[bad[0]]:g} is not positive{more}")


def _whole(path, name: str, values: np.ndarray, line: np.ndarray) -> np.ndarray:
    """``values`` as int64; an id that is not a whole number (a column read as the wrong quantity) is refused,
    where a cast would cut it, or turn one beyond int64 into a RuntimeWarning and a meaningless id."""
    bad = np.flatnonzero(~((values == np.round(values)) & (np.abs(values) < 2.0 ** 53)))
    if len(bad):
        raise ModelFileError(path, f"line {line[bad[0]]}", f"{name} {values[bad[0]]:g} is not a whole number")
    return values.astype(np.int64)


def _parent_rows(path, col, line) -> np.ndarray:
    """Parent ids as rows (-1: none). Ids are the ``id`` column, else 1-based line numbers (TreeQSM)."""
    n = len(line)
    if "parent" not in col:
        return np.full(n, -1)
    ids = _whole(path, "id", col["id"], line) if "id" in col else np.arange(1, n + 1)
    row_of = {int(i): r for r, i in enumerate(ids)}
    parents = _whole(path, "parent", col["parent"], line)
    rows = np.array([row_of.get(int(p), -1) for p in parents])
    _check_no_loops(path, rows, line)
    return rows


def _check_no_loops(path, parent: np.ndarray, line: np.ndarray) -> None:
    """Refuse parents that lead round in a loop (a cylinder its own parent or ancestor): such a tree has
    no tip cylinders to carry leaves. ``parent`` (n,) rows, -1 for none."""
    up = parent.copy()
    for _ in range(len(parent).bit_length()):   # up: the ancestor 2^k generations up, -1 past the base
        up = np.where(up >= 0, up[np.maximum(up, 0)], -1)
    if np.any(up >= 0):   # more generations than cylinders: a loop, which up now points into
        raise ModelFileError(path, f"line {line[up[up >= 0][0]]}", "the cylinder is its own ancestor (the parent "
                             "ids go round in a loop); check the parent and id columns")
