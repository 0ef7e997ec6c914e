"""The declared form a Dask task's outcome crosses the wire in: arrays, numbers, text.

A worker answers with :func:`answer_of` (a result) or :func:`error_answer` (what the run
raised): a value of msgpack's own types only (dicts with text keys, lists, text, numbers,
booleans, None, bytes), which Dask sends with its ``msgpack`` serializer, the only one the
daemon's client accepts. The daemon reads it with :func:`read_answer`, driven by the types it
declares (:class:`~grassd.daemon.core.calibration.result.CalibrationResult` and its parts for a
calibration, :class:`~grassd.daemon.offline.sweep.ConditionResult` for a sweep's condition),
never by anything the wire names: an array is (dtype, shape, bytes) and must have the
declared dtype, a shape within :data:`MAX_NDIM` / :data:`MAX_ARRAY_BYTES` and only finite
entries; a float is a number (NaN stands for "not measured"; infinities are refused); a
dataclass gets exactly its fields and runs its own checks; an error is one of the
calibration's own error types, by name.
Anything else raises :class:`~grassd.daemon.core.errors.ComputeResultRefused`.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeAlias, TypedDict, TypeVar

import numpy as np

from grassd.calib.errors import CalibError
from grassd.daemon.core.errors import CalibrationRejected, ComputeResultRefused
from grassd.sim.errors import SimError

#: the most dimensions an array of a result may have
MAX_NDIM = 3
#: the most bytes one array of a result may have (per-pixel tables of a large display fit)
MAX_ARRAY_BYTES = 256 * 1024 * 1024
#: how deep plain data (report summaries) may nest
MAX_DEPTH = 16
#: the longest text an answer may hold (characters)
MAX_TEXT = 64 * 1024
#: the error types a worker may name, with their subclasses (what ``Calibrator.run`` raises)
ERROR_BASES: tuple[type[Exception], ...] = (CalibError, SimError, CalibrationRejected)

__all__ = ["answer_of", "error_answer", "read_answer", "to_wire", "from_wire"]

WireValue: TypeAlias = (None | bool | int | float | str | bytes | list["WireValue"]
                        | dict[str, "WireValue"])
"""A value of msgpack's own types, as an answer holds them."""

T = TypeVar("T")


class WireError(TypedDict):
    """What a run raised, as it crosses the wire: the names of its classes within
    :data:`ERROR_BASES` (most specific first), its type's name and its message."""

    kinds: list[str]
    type: str
    message: str


class ResultAnswer(TypedDict):
    """A worker's answer carrying a result, in its wire form."""

    result: WireValue


class ErrorAnswer(TypedDict):
    """A worker's answer carrying what the run raised."""

    error: WireError


# --------------------------------------------------------------------------- encoding


def to_wire(value: object) -> WireValue:
    """``value`` (dataclasses, arrays, numbers, text, enums, containers of them) as msgpack's
    own types: a dataclass as a dict of its fields, an array as [dtype, shape, bytes], an enum
    member as its value. Anything else raises TypeError."""
    if isinstance(value, enum.Enum):
        return to_wire(value.value)
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        return value
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        return [a.dtype.str, list(a.shape), a.tobytes()]
    if isinstance(value, np.generic):
        return value.item()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_wire(getattr(value, f.name))
                for f in dataclasses.fields(value) if f.init}
    if isinstance(value, Mapping):
        return {str(k): to_wire(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_wire(v) for v in value]
    raise TypeError(f"{type(value).__name__} has no declared wire form")


def answer_of(result: object) -> ResultAnswer:
    """A worker's answer carrying ``result`` (a CalibrationResult, a sweep's
    ConditionResult)."""
    return {"result": to_wire(result)}


def error_answer(exc: BaseException) -> ErrorAnswer:
    """A worker's answer carrying what the run raised: the names of its classes within
    :data:`ERROR_BASES` (most specific first; none for any other error), its type's name and
    its message."""
    kinds = [_name(c) for c in type(exc).__mro__
             if isinstance(c, type) and issubclass(c, ERROR_BASES)]
    return {"error": {"kinds": kinds, "type": type(exc).__name__,
                      "message": str(exc)[:MAX_TEXT]}}


def _name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


# --------------------------------------------------------------------------- decoding


def read_answer(answer: object, result_type: type[T], where: str) -> T:
    """The result a worker's ``answer`` carries, decoded as ``result_type``; an error it
    carries is raised as its own type (the first of its kinds known here). ``where`` names the
    worker in messages. Raises :class:`ComputeResultRefused` for anything else."""
    if not isinstance(answer, Mapping) or len(answer) != 1:
        raise ComputeResultRefused(f"{where} answered {_what(answer)}, not a grassd answer")
    if "result" in answer:
        result: T = from_wire(result_type, answer["result"], "result", where)
        return result
    if "error" in answer:
        raise _error_of(answer["error"], where)
    raise ComputeResultRefused(f"{where} answered a dict with {sorted(map(str, answer))!r}")


def _error_of(err: object, where: str) -> Exception:
    known = _error_types()
    if not (isinstance(err, Mapping) and set(err) == {"kinds", "type", "message"}
            and isinstance(err["message"], str) and isinstance(err["type"], str)
            and isinstance(err["kinds"], (list, tuple))):
        return ComputeResultRefused(f"{where} answered a malformed error: {_what(err)}")
    message = err["message"][:MAX_TEXT]
    for kind in err["kinds"]:
        cls = known.get(kind) if isinstance(kind, str) else None
        if cls is None:
            continue
        try:
            return cls(message)
        except TypeError:  # a constructor that needs more than a message: its base's
            continue
    return ComputeResultRefused(f"the run failed on {where}: {err['type'][:200]}: {message}")


def _error_types() -> dict[str, type[Exception]]:
    """Every class of :data:`ERROR_BASES` known in this process, by module-qualified name."""
    out: dict[str, type[Exception]] = {}
    todo = list(ERROR_BASES)
    while todo:
        c = todo.pop()
        out[_name(c)] = c
        todo.extend(c.__subclasses__())
    return out


def _what(v: object) -> str:
    return f"a {type(v).__name__}"


def from_wire(tp: Any, v: Any, path: str, where: str) -> Any:
    """``v`` decoded as the declared type ``tp`` (see the module docstring); ``path`` names
    the value in messages. Raises :class:`ComputeResultRefused`."""
    def refuse(msg: str) -> ComputeResultRefused:
        return ComputeResultRefused(f"{where} answered a result whose {path} {msg}")

    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return _plain(v, path, where, 0)
    if origin in (typing.Union, types.UnionType):
        if v is None and type(None) in args:
            return None
        others = [a for a in args if a is not type(None)]
        if len(others) != 1:
            raise TypeError(f"{path}: a union of {others} has no declared wire form")
        return from_wire(others[0], v, path, where)
    if tp is type(None):
        if v is not None:
            raise refuse(f"is {_what(v)}, not None")
        return None
    if tp is bool:
        if not isinstance(v, bool):
            raise refuse(f"is {_what(v)}, not true/false")
        return v
    if tp is int:
        if not isinstance(v, int) or isinstance(v, bool):
            raise refuse(f"is {_what(v)}, not an integer")
        return v
    if tp is float:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise refuse(f"is {_what(v)}, not a number")
        if math.isinf(v):
            raise refuse("is infinite")
        return float(v)
    if tp is str:
        if not isinstance(v, str) or len(v) > MAX_TEXT:
            raise refuse(f"is {_what(v)}, not a text of at most {MAX_TEXT} characters")
        return v
    if origin is np.ndarray:
        return _array(args, v, refuse)
    if dataclasses.is_dataclass(tp):
        return _dataclass(tp, v, path, where, refuse)
    if typing.is_typeddict(tp):
        return _typed_dict(tp, v, path, where, refuse)
    if origin is typing.Literal:
        if not any(v == a and type(v) is type(a) for a in args):
            raise refuse(f"is {_what(v)}, not one of {list(args)!r:.200}")
        return v
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(v)
        except ValueError:
            raise refuse(f"is {_what(v)}, not a {tp.__name__}") from None
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):
            raise refuse(f"is {_what(v)}, not a list")
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(v) != len(args):
                raise refuse(f"has {len(v)} entries, not {len(args)}")
            return tuple(from_wire(a, x, f"{path}[{i}]", where)
                         for i, (a, x) in enumerate(zip(args, v, strict=True)))
        out = [from_wire(args[0], x, f"{path}[{i}]", where) for i, x in enumerate(v)]
        return tuple(out) if origin is tuple else out
    if origin in (dict, Mapping) or origin is typing.get_origin(Mapping[str, int]):
        if not isinstance(v, Mapping) or not all(isinstance(k, str) for k in v):
            raise refuse(f"is {_what(v)}, not a table with text keys")
        return {k: from_wire(args[1], x, f"{path}[{k!r}]", where) for k, x in v.items()}
    raise TypeError(f"{path}: {tp!r} has no declared wire form")


def _array(args: tuple[Any, ...], v: Any, refuse: Any) -> np.ndarray:
    """An array of the declared dtype (``NDArray[dtype]``'s arguments) from [dtype, shape,
    bytes], checked (see the module docstring)."""
    want = np.dtype(typing.get_args(args[1])[0]) if len(args) == 2 else None
    if not (isinstance(v, (list, tuple)) and len(v) == 3 and isinstance(v[0], str)
            and isinstance(v[1], (list, tuple)) and isinstance(v[2], bytes)):
        raise refuse(f"is {type(v).__name__}, not an array (dtype, shape, bytes)")
    dtype_str, shape, data = v
    if want is None or dtype_str != want.str:
        raise refuse(f"has dtype {dtype_str[:20]!r}, not {None if want is None else want.str!r}")
    if (len(shape) > MAX_NDIM
            or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)):
        raise refuse(f"has the shape {tuple(shape)!r:.80}, not at most {MAX_NDIM} sizes")
    nbytes = math.prod(shape) * want.itemsize
    if nbytes > MAX_ARRAY_BYTES or len(data) != nbytes:
        raise refuse(f"has {len(data)} bytes for the shape {tuple(shape)} ({nbytes} expected, "
                     f"at most {MAX_ARRAY_BYTES})")
    a = np.frombuffer(data, dtype=want).reshape(shape).copy()
    if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
        raise refuse("holds entries that are not finite")
    return a


def _dataclass(tp: type, v: Any, path: str, where: str, refuse: Any) -> Any:
    hints = typing.get_type_hints(tp)
    names = [f.name for f in dataclasses.fields(tp) if f.init]
    if not isinstance(v, Mapping) or set(v) != set(names):
        got = sorted(map(str, v)) if isinstance(v, Mapping) else _what(v)
        raise refuse(f"is not a {tp.__name__} (fields {names}, got {got!r:.200})")
    fields = {n: from_wire(hints[n], v[n], f"{path}.{n}", where) for n in names}
    try:
        return tp(**fields)
    except (ValueError, TypeError, ArithmeticError, CalibError, SimError) as exc:
        raise refuse(f"is not a valid {tp.__name__}: {exc}") from None


def _typed_dict(tp: type, v: object, path: str, where: str, refuse: Any) -> dict[str, Any]:
    """A TypedDict's value: its required keys, any of its optional ones, nothing else, each
    decoded as declared."""
    hints = typing.get_type_hints(tp)
    required = _required_keys(tp)
    if (not isinstance(v, Mapping) or not all(isinstance(k, str) for k in v)
            or not required <= set(v) or not set(v) <= set(hints)):
        got = sorted(map(str, v)) if isinstance(v, Mapping) else _what(v)
        raise refuse(f"is not a {tp.__name__} (keys {sorted(hints)}, of which "
                     f"{sorted(required)} required; got {got!r:.200})")
    return {k: from_wire(hints[k], x, f"{path}[{k!r}]", where) for k, x in v.items()}


def _required_keys(tp: type) -> set[str]:
    """A TypedDict's required keys, read from its annotations and its own totality (keys
    inherited from a base of the other totality need ``Required``/``NotRequired``):
    ``__required_keys__`` counts a ``NotRequired`` in a string annotation as required."""
    total = getattr(tp, "__total__", True)
    out: set[str] = set()
    for k, hint in typing.get_type_hints(tp, include_extras=True).items():
        marked = typing.get_origin(hint)
        if marked is typing.Required or (total and marked is not typing.NotRequired):
            out.add(k)
    return out


def _plain(v: Any, path: str, where: str, depth: int) -> Any:
    """Plain data (report summaries): text, numbers, booleans, None, lists, text-keyed
    tables, at most :data:`MAX_DEPTH` deep."""
    if depth > MAX_DEPTH:
        raise ComputeResultRefused(f"{where} answered a result whose {path} nests deeper "
                                   f"than {MAX_DEPTH}")
    if v is None or isinstance(v, (bool, int, float)):
        return v
    if isinstance(v, str) and len(v) <= MAX_TEXT:
        return v
    if isinstance(v, (list, tuple)):
        return [_plain(x, path, where, depth + 1) for x in v]
    if isinstance(v, Mapping) and all(isinstance(k, str) for k in v):
        return {k: _plain(x, path, where, depth + 1) for k, x in v.items()}
    raise ComputeResultRefused(f"{where} answered a result whose {path} is {_what(v)}, not "
                               "plain data")
