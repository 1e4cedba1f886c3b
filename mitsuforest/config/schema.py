"""A small declarative schema: typed fields with defaults and bounds, nested in mappings.

Each field parses one YAML value and raises :class:`~mitsuforest.errors.ConfigError` naming the
file, the dotted key path and the reason. Mappings reject unknown keys with a "did you mean".
"""

from __future__ import annotations

import copy
import difflib
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..errors import ConfigError

REQUIRED = object()
_FLOAT_MAX = sys.float_info.max


@dataclass
class Context:
    """Where values come from: the file (for messages) and its folder (for relative paths)."""

    file: Path

    @property
    def folder(self) -> Path:
        return self.file.resolve().parent

    def fail(self, key: str, reason: str):
        raise ConfigError(self.file, key, reason)


def _type_name(value) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", bool: "true/false"}.get(
        type(value), type(value).__name__)


@dataclass
class Number:
    default: Any = REQUIRED
    integer: bool = False
    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    lt: float | None = None
    nullable: bool = False
    unit_hint: str = ""    # said after a value above the bounds, where a smaller unit is the likely cause

    def parse(self, value, ctx: Context, key: str):
        if value is None and self.nullable:
            return None
        kind = "an integer" if self.integer else "a number"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            if isinstance(value, str):
                try:
                    value = float(value)  # YAML reads 0.5e-3 as a string
                except ValueError:
                    ctx.fail(key, f"must be {kind}, got {value!r}")
            else:
                ctx.fail(key, f"must be {kind}, got {_type_name(value)}")
        if isinstance(value, int) and abs(value) > _FLOAT_MAX:   # YAML reads 400 digits as an int, beyond float64
            ctx.fail(key, f"must be within ±{_FLOAT_MAX:.1e} (float64), got an integer of about "
                          f"{int(value.bit_length() * math.log10(2)) + 1} digits")
        if not math.isfinite(value):
            ctx.fail(key, f"must be finite, got {value}")
        if self.integer:
            if isinstance(value, float) and not value.is_integer():   # not float(int): exact for ints of any size
                ctx.fail(key, f"must be an integer, got {value}")
            value = int(value)
        for bound, ok, word in ((self.gt, lambda b: value > b, ">"), (self.ge, lambda b: value >= b, ">="),
                                (self.lt, lambda b: value < b, "<"), (self.le, lambda b: value <= b, "<=")):
            if bound is not None and not ok(bound):
                slipped = self.unit_hint and word.startswith("<")     # a value in a smaller unit is too large
                ctx.fail(key, f"must be {word} {bound:g}, got {value:g}" + (f" ({self.unit_hint})" if slipped else ""))
        return value


@dataclass
class Text:
    default: Any = REQUIRED
    choices: tuple[str, ...] | None = None
    nullable: bool = False

    def parse(self, value, ctx: Context, key: str):
        if value is None and self.nullable:
            return None
        if not isinstance(value, str):
            ctx.fail(key, f"must be a string, got {_type_name(value)}")
        if self.choices and value not in self.choices:
            ctx.fail(key, f"must be one of {', '.join(self.choices)}, got {value!r}" + _did_you_mean(value, self.choices))
        return value


@dataclass
class Flag:
    """``true`` or ``false`` (YAML's other spellings of them, ``yes``/``no``, are read as these by PyYAML)."""

    default: Any = REQUIRED

    def parse(self, value, ctx: Context, key: str):
        if not isinstance(value, bool):
            ctx.fail(key, f"must be true or false, got {value!r}")
        return value


@dataclass
class FilePath(Text):
    """A path, resolved against the folder of the file that names it."""

    must_exist: bool = True

    def parse(self, value, ctx: Context, key: str):
        value = super().parse(value, ctx, key)
        if value is None:
            return None
        if not value.strip():
            ctx.fail(key, "must name a file, got an empty path")
        path = (ctx.folder / Path(value).expanduser()).resolve()
        try:
            if self.must_exist and not path.exists():
                ctx.fail(key, f"file not found: {path}")
            if self.must_exist and not path.is_file():
                ctx.fail(key, f"not a file ({'a folder' if path.is_dir() else 'a device, pipe or socket'}): {path}")
        except OSError as e:   # a name too long for the file system, say
            ctx.fail(key, f"cannot be read ({e.strerror or e}): {path}")
        return str(path)


@dataclass
class Vector:
    """A fixed-length list of numbers, each checked by ``item``."""

    length: int
    item: Number = field(default_factory=Number)
    default: Any = REQUIRED
    scalar_ok: bool = False  # a single number stands for all components

    def parse(self, value, ctx: Context, key: str):
        if self.scalar_ok and not isinstance(value, list):
            return [self.item.parse(value, ctx, key)] * self.length
        if not isinstance(value, list) or len(value) != self.length:
            ctx.fail(key, f"must be a list of {self.length} numbers, got {value!r}")
        return [self.item.parse(v, ctx, f"{key}[{i}]") for i, v in enumerate(value)]


@dataclass
class ListOf:
    item: Any
    default: Any = REQUIRED
    min_length: int = 0
    nullable: bool = False
    unique: bool = False

    def parse(self, value, ctx: Context, key: str):
        if value is None and self.nullable:
            return None
        if not isinstance(value, list):
            ctx.fail(key, f"must be a list, got {_type_name(value)}")
        if len(value) < self.min_length:
            ctx.fail(key, f"must have at least {self.min_length} entries")
        items = [parse(self.item, v, ctx, f"{key}[{i}]") for i, v in enumerate(value)]
        if self.unique:
            for i, item in enumerate(items):
                if item in items[:i]:
                    ctx.fail(f"{key}[{i}]", f"{item!r} is given twice (also {key}[{items.index(item)}])")
        return items


@dataclass
class Custom:
    """A field parsed by a function ``fn(value, ctx, key)``."""

    fn: Callable
    default: Any = REQUIRED

    def parse(self, value, ctx: Context, key: str):
        return self.fn(value, ctx, key)


MAX_NAME_BYTES = 200   # names make file and folder names: most file systems allow 255 bytes, suffixes included


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot name the files (or folder) a run writes, or ``None`` if it can: it must be a
    plain, visible file name."""
    if not name:
        return "must not be empty"
    if any(c in name for c in "/\\\0"):
        return f"must be a plain file name, without / or \\, got {name!r}"
    if any(ord(c) < 32 or 127 <= ord(c) < 160 for c in name):   # newlines, tabs, terminal escape codes
        return f"must not hold control characters, got {name!r}"
    if name.startswith("."):
        return f"must not start with a dot (a hidden file; . and .. are folders), got {name!r}"
    if len(name.encode()) > MAX_NAME_BYTES:
        return f"must be at most {MAX_NAME_BYTES} bytes long, got {len(name.encode())}"
    return None


def _did_you_mean(word: str, choices) -> str:
    close = difflib.get_close_matches(str(word), list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def parse_mapping(spec: dict, value, ctx: Context, key: str = "") -> dict:
    """Parse a mapping against ``spec``: every key known, defaults filled in, nested mappings recursed."""
    if value is None:
        value = {}
    if not isinstance(value, dict):
        ctx.fail(key or "(top level)", f"must be a mapping, got {_type_name(value)}")
    for name in value:
        if name not in spec:
            where = f"{key}.{name}" if key else str(name)
            ctx.fail(where, "unknown key" + _did_you_mean(name, spec))
    out = {}
    for name, sub in spec.items():
        where = f"{key}.{name}" if key else name
        if name in value:
            out[name] = parse(sub, value[name], ctx, where)
        elif isinstance(sub, dict):
            out[name] = parse_mapping(sub, {}, ctx, where)
        elif sub.default is REQUIRED:
            ctx.fail(where, "is required")
        elif isinstance(sub, Custom):
            out[name] = sub.parse(copy.deepcopy(sub.default), ctx, where)
        else:
            out[name] = copy.deepcopy(sub.default)
    return out


def parse(spec, value, ctx: Context, key: str):
    if isinstance(spec, dict):
        return parse_mapping(spec, value, ctx, key)
    return spec.parse(value, ctx, key)
