"""Reading TOML documents (finger files, study files) with messages that point at the
mistake.

`TomlReader` holds typed accessors (`table`, `number`, `integer`, `boolean`, `string`,
`choice`, `vector`, ...): each checks one value and returns it, or raises a
`FingerFileError` that names the file, the key path and the value as the user wrote it,
with a suggestion where a close spelling or a synonym exists.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import tomllib


class FingerFileError(ValueError):
    """An invalid finger file. The message names the file, the key path and the value."""


# Words users write for a choice, by what they mean (a spelling match would send
# "fixed" to "pinned").
_SYNONYMS = {
    "fixed": ("clamped",),
    "clamp": ("clamped",),
    "built-in": ("clamped",),
    "encastre": ("clamped",),
    "hinge": ("pinned",),
    "hinged": ("pinned",),
    "pin": ("pinned",),
    "released": ("free",),
    "none": ("free",),
    "2d": ("planar",),
    "plane": ("planar",),
    "in-plane": ("planar",),
    "3d": ("spatial",),
    "3-d": ("spatial",),
}

_BEFORE_TABLES = "a top-level key must come before the first [table] in the file"

#: What a key means, added to the message when a required key is missing.
KEY_HELP = {
    "E": " (Young's modulus, MPa)",
    "nu": " (Poisson's ratio)",
    "base": " (base point [x, z], mm)",
    "tip": " (tip point [x, z], mm, shared by both beams)",
    "thickness": " (in-plane thickness, mm)",
    "depth": " (out-of-plane depth, mm)",
    "front_s": " (arc length on the front beam, mm)",
    "back_s": " (arc length on the back beam, mm)",
    "kind": ' ("point" or "distributed")',
    "beam": ' ("front", "back" or a crossbeam index)',
    "s": " (arc length of a point load, mm)",
    "s_range": " ([s0, s1] of a distributed load, mm)",
    "force": " (point force [Fx, Fy, Fz], N)",
    "total_force": " (resultant [Fx, Fy, Fz] of a distributed load, N)",
    "count": " (number of crossbeams)",
    "material": " (table [material] with E and nu)",
    "front": " (table [front] with base, tip, thickness, depth)",
    "back": " (table [back] with base, thickness, depth)",
}


def show(v) -> str:
    """A value as the user wrote it in TOML."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(show(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {show(x)}" for k, x in v.items()) + "}"
    return repr(v)


def type_name(v) -> str:
    """The TOML type of a value, with its article ("a number", "an array")."""
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__


class TomlReader:
    """Typed accessors for one TOML document; `source` names it in every message."""

    def __init__(self, source: str):
        self.source = source
        # The document and its allowed top-level keys, once its top-level table is
        # checked: a top-level key written after a [table] is, in TOML, a key of that
        # table, and the messages about it say so (when the document has no such key at
        # its top level: a crossbeam's `front` is a misspelt front_s, not the [front]).
        self.doc: dict = {}
        self.top_keys: tuple = ()

    def error(self, path: str, problem: str, value=dataclasses.MISSING) -> FingerFileError:
        if value is dataclasses.MISSING:
            return FingerFileError(f"{self.source}: {path}: {problem}")
        return FingerFileError(f"{self.source}: {path} = {show(value)}: {problem}")

    # -- tables --------------------------------------------------------------------

    def table(self, value, path: str, allowed, required=(), hints=None) -> dict:
        """Check that `value` is a table with only `allowed` keys and all `required` ones."""
        if not isinstance(value, dict):
            raise self.error(path, f"expected a table [{path}], got {type_name(value)}", value)
        if not path:
            self.doc, self.top_keys = value, tuple(allowed)
        hints = hints or {}
        for key in value:
            if key not in allowed:
                raise self.unknown_key(value, path, key, allowed, hints)
        for key in required:
            if key not in value:
                full = f"{path}.{key}" if path else key
                more = KEY_HELP.get(key, "") + self.misplaced(path, key)
                raise self.error(full, "missing required key" + more)
        return value

    def unknown_key(self, value: dict, path: str, key: str, allowed, hints) -> FingerFileError:
        """The error for `key`, not one of `allowed` in the table at `path`: its hint, or
        a top-level key written below a table, or the closest allowed spelling."""
        full = f"{path}.{key}" if path else key
        if key in hints:
            return self.error(full, hints[key], value[key])
        if path and key in self.top_keys and key not in self.doc:
            hint = (
                f" ('{key}' is a top-level key, and {_BEFORE_TABLES}: TOML reads it as {full} here)"
            )
        else:
            close = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
        where = f"in [{path}]" if path else "at the top level"
        known = ", ".join(allowed)
        return self.error(full, f"unknown key {where}{hint}; known keys: {known}", value[key])

    def misplaced(self, path: str, key: str) -> str:
        """For a missing top-level key that the document has inside one of its tables
        (written after that table's header), a hint saying so; else ""."""
        if path:
            return ""
        for name, tbl in self.doc.items():
            if isinstance(tbl, list) and tbl and all(isinstance(x, dict) for x in tbl):
                name, tbl = f"{name}[{len(tbl) - 1}]", tbl[-1]
            if isinstance(tbl, dict) and key in tbl:
                return (
                    f" (the file has {name}.{key}: {_BEFORE_TABLES}, or TOML reads it as a "
                    f"key of the table above it)"
                )
        return ""

    def array_of_tables(self, value, path: str) -> list:
        if isinstance(value, dict):
            raise self.error(
                path,
                f"expected an array of tables written [[{path}]] (one per entry), got a "
                f"single table [{path}]",
            )
        if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
            raise self.error(path, f"expected an array of tables [[{path}]]", value)
        return value

    # -- scalars -------------------------------------------------------------------

    def number(self, value, path: str, *, positive=False, nonnegative=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(path, f"expected a number, got {type_name(value)}", value)
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the float range
            x = math.inf
        if not math.isfinite(x):
            raise self.error(path, "must be a finite number", value)
        if positive and x <= 0:
            raise self.error(path, "must be positive", value)
        if nonnegative and x < 0:
            raise self.error(path, "must not be negative", value)
        return x

    def integer(self, value, path: str, *, minimum=None, maximum=None, why="") -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(path, f"expected an integer, got {type_name(value)}", value)
        if minimum is not None and value < minimum:
            raise self.error(path, f"must be an integer >= {minimum}", value)
        if maximum is not None and value > maximum:
            raise self.error(path, f"must be an integer <= {maximum}{why}", value)
        return value

    def boolean(self, value, path: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(path, f"expected true or false, got {type_name(value)}", value)
        return value

    def string(self, value, path: str, choices=None) -> str:
        if not isinstance(value, str):
            raise self.error(path, f"expected a string, got {type_name(value)}", value)
        if choices is not None and value not in choices:
            close = [c for c in _SYNONYMS.get(value.lower(), ()) if c in choices]
            close = close or difflib.get_close_matches(value, list(choices), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            options = " | ".join(f'"{c}"' for c in choices)
            raise self.error(path, f"must be one of {options}{hint}", value)
        return value

    def choice(self, value, path: str, named: dict):
        """The object a word names (`named`: word -> object)."""
        return named[self.string(value, path, tuple(named))]

    def vector(self, value, path: str, n: int, what: str) -> list[float]:
        if not isinstance(value, list):
            raise self.error(path, f"expected {what}, an array of {n} numbers", value)
        if len(value) != n:
            raise self.error(
                path, f"expected {what}, an array of {n} numbers, got {len(value)}", value
            )
        for i, x in enumerate(value):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise self.error(
                    path,
                    f"expected {what}, an array of {n} numbers; element {i} is {type_name(x)}",
                    value,
                )
            if not math.isfinite(float(x)):
                raise self.error(path, f"element {i} must be a finite number", value)
        return [float(x) for x in value]


def parse_toml(text: str, source: str, error: type[FingerFileError]) -> dict:
    """The document in `text`, or `error` naming `source` when it is not valid TOML."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{source}: not valid TOML: {e}") from None


def read_text(path, what: str, error: type[FingerFileError]) -> str:
    """The UTF-8 text of the `what` file at `path`, or `error` saying why it cannot be
    read."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as e:
        raise error(f"{path}: cannot read the {what} file: {e.strerror}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: not UTF-8 text: {e}") from None


def require_keys(r: TomlReader, table: dict, path: str, keys, hints: dict) -> None:
    """Raise for the first of `keys` missing from `table` (at `path`), with its hint."""
    for key in keys:
        if key not in table:
            full = f"{path}.{key}" if path else key
            raise r.error(
                full, "missing required key" + hints.get(key, "") + r.misplaced(path, key)
            )
