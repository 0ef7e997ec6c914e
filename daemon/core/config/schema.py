"""Validation of TOML (and JSON) documents against a schema, with key and line in every error.

One machinery for every document a user writes: the daemon's configuration
(:mod:`grassd.daemon.core.config.settings`), a bundle manifest
(:mod:`grassd.daemon.core.store.manifest`) and a capture directory's ``capture.toml``
(:mod:`grassd.daemon.offline.validate`). A schema maps each key of a table to a :class:`Field`
(type, default, extra check); :func:`table` checks a table against it (an unknown key, a missing
required key, a wrong type -- ``true`` where a number belongs; ``1`` is accepted for a float, never
for a bool -- or a failed check) and raises the document's error type naming the dotted key and the
line. :func:`schema` takes the defaults of a table that fills a dataclass from the dataclass's
fields, so every default is written once.

How the line is found: :mod:`tomllib` reports positions only for syntax errors, so after parsing
we scan the raw text line by line, tracking the current table header (``[a.b]`` and ``[[a]]``,
counting repeated array-of-tables headers so ``controllers[2]`` means the third
``[[controllers]]``). A key's line is the first ``key =`` line (bare or quoted key, or a dotted
key whose first part is the key) inside its table's header block; a table's line is its header.
Keys written inside inline tables or multi-line arrays fall back to the line of the enclosing key
or header. The scan ignores comments and multi-line strings only approximately (a line starting
with ``key =`` inside a multi-line string could be mistaken for the key); that only affects the
reported line, never the validation itself. A JSON document has no such lines: pass ``""`` as its
text and errors name the key only.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import re
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias, TypeVar, overload

from grassd.daemon.core.errors import ConfigError, LocatedError

#: A value of a parsed document: what :mod:`tomllib` gives (a JSON document's values are the
#: same kinds, with null as None).
TomlValue: TypeAlias = (str | int | float | bool | None | datetime.datetime | datetime.date
                        | datetime.time | list["TomlValue"] | dict[str, "TomlValue"])
#: A table of a parsed document.
TomlTable: TypeAlias = dict[str, TomlValue]

_T = TypeVar("_T")

# --------------------------------------------------------------------------- line locator


_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY_RE = re.compile(r"""^\s*("(?:[^"\\]|\\.)*"|'[^']*'|[A-Za-z0-9_-]+)\s*[.=]""")


def _split_dotted(name: str) -> list[str]:
    parts = []
    for m in re.finditer(r"""\s*("(?:[^"\\]|\\.)*"|'[^']*'|[^.\s]+)\s*(?:\.|$)""", name):
        p = m.group(1)
        if p[:1] in "\"'":
            p = p[1:-1]
        parts.append(p)
    return parts


class LineLocator:
    """Maps table paths and keys of a TOML text to 1-based line numbers (see module docstring)."""

    def __init__(self, text: str) -> None:
        # table path (tuple, with array indices) -> (header line, {key: line})
        self._tables: dict[tuple, tuple[int, dict[str, int]]] = {(): (1, {})}
        counts: dict[tuple, int] = {}
        current: tuple = ()
        for lineno, raw in enumerate(text.splitlines(), start=1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            hm = _HEADER_RE.match(line) if line.startswith("[") else None
            if hm:
                parts = _split_dotted(hm.group(2))
                # Resolve parent parts to the latest index of arrays of tables.
                resolved: list = []
                for part in parts[:-1]:
                    resolved.append(part)
                    if tuple(resolved) in counts:
                        resolved.append(counts[tuple(resolved)] - 1)
                resolved.append(parts[-1])
                key = tuple(resolved)
                if hm.group(1) == "[[":
                    idx = counts.get(key, 0)
                    counts[key] = idx + 1
                    key = key + (idx,)
                current = key
                self._tables.setdefault(current, (lineno, {}))
                continue
            km = _KEY_RE.match(line)
            if km:
                k = km.group(1)
                if k[:1] in "\"'":
                    k = k[1:-1]
                self._tables.setdefault(current, (lineno, {}))[1].setdefault(k, lineno)

    def line_of(self, path: tuple) -> int | None:
        """Line of the key or table at ``path`` (e.g. ``("controllers", 1, "baud")``)."""
        path = tuple(path)
        for cut in range(len(path), 0, -1):
            table, key = path[: cut - 1], path[cut - 1]
            if path[:cut] in self._tables:
                return self._tables[path[:cut]][0]
            if table in self._tables and isinstance(key, str):
                line = self._tables[table][1].get(key)
                if line is not None:
                    return line
        return None


# --------------------------------------------------------------------------- validation


def key_path(path: tuple) -> str:
    """The dotted name of a key path: ``("controllers", 1, "baud")`` -> ``controllers[1].baud``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


class Context:
    """One document being validated: its text (for line numbers), the name it is reported under
    (``source``), the directory relative paths resolve against, and the error type it raises
    (constructed as ``error(message, key=dotted key, line=line, path=source)``)."""

    def __init__(self, text: str, source: str | None, base_dir: Path | None = None,
                 error: type[LocatedError] = ConfigError) -> None:
        self.locator = LineLocator(text)
        self.source = source
        self.base_dir = base_dir if base_dir is not None else Path.cwd()
        self.error_type = error

    def error(self, path: tuple, message: str) -> LocatedError:
        """The error for the key or table at ``path`` (its dotted name and line are added)."""
        return self.error_type(
            message, key=key_path(path) or None, line=self.locator.line_of(path), path=self.source
        )


#: How an error names each kind of value.
TYPE_NAMES: dict[type | types.UnionType, str] = {
    int: "an integer", float: "a finite number", str: "a string", bool: "true or false",
    list: "an array", dict: "a table"}


@overload
def check_type(ctx: Context, path: tuple, value: TomlValue, kind: type[_T],
               hint: str | None = None) -> _T: ...


@overload
def check_type(ctx: Context, path: tuple, value: TomlValue, kind: types.UnionType,
               hint: str | None = None) -> TomlValue: ...


def check_type(ctx: Context, path: tuple, value: TomlValue, kind: type[_T] | types.UnionType,
               hint: str | None = None) -> _T | TomlValue:
    """``value`` of the key at ``path`` checked to be a ``kind`` (a type or a union of types; an
    int is taken as a float, a bool never as a number; floats must be finite); raises
    ``ctx.error`` otherwise, naming the expected value as ``hint`` or by :data:`TYPE_NAMES`."""
    ok = isinstance(value, kind) and not (kind in (int, float) and isinstance(value, bool))
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        ok, value = True, float(value)
    if not ok:
        got = type(value).__name__
        raise ctx.error(path, f"must be {hint or TYPE_NAMES[kind]}, got {got} {value!r}")
    if kind is float and isinstance(value, float) and not math.isfinite(value):
        raise ctx.error(path, f"must be a finite number, got {value!r}")
    return value


#: The default of a required key.
MISSING = object()


@dataclass
class Field:
    """Schema of one key: type (or union of types), default (``MISSING`` = required), extra
    check, and how messages name the expected value (``hint``; default :data:`TYPE_NAMES`)."""

    kind: type | types.UnionType
    default: Any = MISSING
    check: Callable[[Any], str | None] | None = None
    hint: str | None = None


def schema(model: type, **keys: Field) -> dict[str, Field]:
    """The schema of a table that fills the dataclass ``model``: a key named like a field of
    ``model`` that has a default takes that default, so every default is written once, on the
    dataclass (a key that has no such field, e.g. a raw value parsed further, keeps its own)."""
    defaults = {f.name: f.default for f in dataclasses.fields(model)
                if f.default is not dataclasses.MISSING}
    out = {}
    for name, f in keys.items():
        if name in defaults:
            if f.default is not MISSING:
                raise TypeError(f"the default of {model.__name__}.{name} is written twice")
            f = dataclasses.replace(f, default=defaults[name])
        out[name] = f
    return out


#: The schemas :func:`table` has checked tables against, while :func:`recording` runs.
_RECORDING: ContextVar[dict[tuple[str, ...], dict[str, Field]] | None] = ContextVar(
    "_RECORDING", default=None)


@contextmanager
def recording() -> Iterator[dict[tuple[str, ...], dict[str, Field]]]:
    """While the block runs, every schema :func:`table` checks a table against, by the table's
    path without array indices (``("controllers",)`` for each ``[[controllers]]``): the keys a
    document may hold, read from the parsers themselves (the first schema of a path is kept)."""
    seen: dict[tuple[str, ...], dict[str, Field]] = {}
    token = _RECORDING.set(seen)
    try:
        yield seen
    finally:
        _RECORDING.reset(token)


def table(ctx: Context, path: tuple, data: TomlValue, fields: dict[str, Field]
          ) -> dict[str, Any]:
    """Validate the table ``data`` at ``path`` against ``fields`` (key -> :class:`Field`);
    return plain values with defaults filled in."""
    seen = _RECORDING.get()
    if seen is not None:
        seen.setdefault(tuple(p for p in path if isinstance(p, str)), fields)
    if not isinstance(data, dict):
        raise ctx.error(path, f"must be a table, got {type(data).__name__}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        allowed = ", ".join(sorted(fields))
        raise ctx.error(path + (unknown[0],), f"unknown key (allowed here: {allowed})")
    out: dict[str, Any] = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is MISSING:
                raise ctx.error(path + (name,),
                                f"required key is missing ({f.hint or TYPE_NAMES[f.kind]})")
            out[name] = f.default
            continue
        value = check_type(ctx, path + (name,), data[name], f.kind, f.hint)
        if f.check is not None:
            msg = f.check(value)
            if msg:
                raise ctx.error(path + (name,), msg)
        out[name] = value
    return out


class Section:
    """One table of a document, checked against its schema when it is read (:meth:`read`);
    it hands out its values with the types the schema named (as each of Klipper's config
    sections hands out ``getfloat``, ``getint``), its tables as sections of their own, and
    errors that name its keys and lines.

    >>> pump = Section.read(Context("rate_l_min = 2", "pump.toml"), (), {"rate_l_min": 2},
    ...                     {"rate_l_min": Field(float, check=positive), "note": Field(str, None)})
    >>> pump.get_float("rate_l_min"), pump.get_opt_str("note"), pump.given("note")
    (2.0, None, False)
    >>> raise pump.error("rate_l_min", "too slow")
    Traceback (most recent call last):
    ...
    grassd.daemon.core.errors.ConfigError: pump.toml:1: rate_l_min: too slow
    """

    def __init__(self, ctx: Context, path: tuple, values: dict[str, Any],
                 given: frozenset[str] = frozenset()) -> None:
        self.ctx, self.path = ctx, path
        self._values = values
        self._given = given

    @classmethod
    def read(cls, ctx: Context, path: tuple, data: TomlValue, fields: dict[str, Field]
             ) -> Section:
        """The table ``data`` at ``path`` checked against ``fields`` (:func:`table`)."""
        values = table(ctx, path, data, fields)
        return cls(ctx, path, values, frozenset(data) if isinstance(data, dict) else frozenset())

    def error(self, key: str | int | tuple, message: str) -> LocatedError:
        """The error for ``key`` (a key path below this table, or one key) of this table."""
        return self.ctx.error(self.path + (key if isinstance(key, tuple) else (key,)), message)

    def given(self, key: str) -> bool:
        """Whether the document wrote ``key`` (else its value is the schema's default)."""
        return key in self._given

    def section(self, key: str, fields: dict[str, Field]) -> Section:
        """The table at ``key`` checked against ``fields``."""
        return Section.read(self.ctx, self.path + (key,), self._values[key], fields)

    def opt_section(self, key: str, fields: dict[str, Field]) -> Section | None:
        """The table at ``key`` checked against ``fields``, or None where its value is None
        (the key was left out)."""
        return None if self._values[key] is None else self.section(key, fields)

    def sections(self, key: str, fields: dict[str, Field]) -> Iterator[Section]:
        """Each table of the array at ``key``, checked against ``fields`` as it is reached."""
        for i, item in enumerate(self.get_list(key)):
            yield Section.read(self.ctx, self.path + (key, i), item, fields)

    def _get(self, key: str, kind: type[_T]) -> _T:
        v = self._values[key]
        if not isinstance(v, kind):
            raise TypeError(f"{key_path(self.path + (key,))} is {type(v).__name__}, not "
                            f"{kind.__name__}: its schema names another kind")
        return v

    def get_str(self, key: str) -> str:
        """The string at ``key``."""
        return self._get(key, str)

    def get_opt_str(self, key: str) -> str | None:
        """The string at ``key``, or None (its default when left out)."""
        return None if self._values[key] is None else self.get_str(key)

    def get_int(self, key: str) -> int:
        """The integer at ``key``."""
        return self._get(key, int)

    def get_float(self, key: str) -> float:
        """The number at ``key`` (a default may be an int)."""
        v = self._values[key]
        return v if isinstance(v, int) and not isinstance(v, bool) else self._get(key, float)

    def get_bool(self, key: str) -> bool:
        """The boolean at ``key``."""
        return self._get(key, bool)

    def get_list(self, key: str) -> list[TomlValue]:
        """The array at ``key``."""
        return self._get(key, list)

    def get_floats(self, key: str) -> tuple[float, ...]:
        """The array of numbers at ``key`` (its check was :func:`numbers`) as floats."""
        return tuple(float(x) for x in self._values[key])

    def get_ints(self, key: str) -> tuple[int, ...]:
        """The array of integers at ``key`` (its check saw to that)."""
        return tuple(int(x) for x in self._values[key])

    def get_float_rows(self, key: str) -> tuple[tuple[float, ...], ...]:
        """The array of arrays of numbers at ``key`` (its check saw to that) as floats."""
        return tuple(tuple(float(x) for x in row) for row in self._values[key])

    def get_as(self, key: str, kind: type[_T]) -> _T:
        """The value at ``key``, a ``kind`` (a default of another type than the document's,
        such as a dataclass)."""
        return self._get(key, kind)

    def get_value(self, key: str) -> TomlValue:
        """The value at ``key`` whose schema allows several kinds (a union)."""
        v: TomlValue = self._values[key]
        return v

    def fill(self, model: type[_T]) -> _T:
        """``model`` built from every value (its schema is ``schema(model, ...)`` with no
        other keys)."""
        return model(**self._values)


# ----------------------------------------------------------------------------- checks
# A check takes a value of the right type and returns None, or what is wrong with it.


@dataclass(frozen=True)
class Between:
    """Check: ``lo <= v <= hi`` (``unit`` is appended to the bounds in the message); its bounds
    stay readable, for the documentation of the key."""

    lo: float
    hi: float
    unit: str = ""

    def __call__(self, v: float) -> str | None:
        if not self.lo <= v <= self.hi:
            return f"must be between {self.lo} and {self.hi}{self.unit}, got {v}"
        return None


def between(lo: float, hi: float, unit: str = "") -> Between:
    """Check: ``lo <= v <= hi`` (``unit`` is appended to the bounds in the message)."""
    return Between(lo, hi, unit)


def positive(v: float) -> str | None:
    """Check: ``v > 0``."""
    return None if v > 0 else f"must be > 0, got {v}"


def non_negative(v: float) -> str | None:
    """Check: ``v >= 0``."""
    return None if v >= 0 else f"must be >= 0, got {v}"


@dataclass(frozen=True)
class OneOf:
    """Check: ``v`` is one of ``choices`` (readable, for the documentation of the key)."""

    choices: tuple[str | int, ...]

    def __call__(self, v: str | int) -> str | None:
        if v in self.choices:
            return None
        return f"must be one of {', '.join(map(repr, self.choices))}; got {v!r}"


def one_of(*choices: str | int) -> OneOf:
    """Check: ``v`` is one of ``choices``."""
    return OneOf(tuple(choices))


def non_empty(v: str) -> str | None:
    """Check: a string that is not blank."""
    return None if v.strip() else "must not be empty"


def numbers(n: int) -> Callable[[list[TomlValue]], str | None]:
    """Check: an array of ``n`` finite numbers."""
    def check(v: list[TomlValue]) -> str | None:
        ok = len(v) == n and all(isinstance(x, int | float) and not isinstance(x, bool)
                                 and math.isfinite(x) for x in v)
        return None if ok else f"must be an array of {n} numbers, got {v!r}"

    return check
