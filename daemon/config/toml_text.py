"""TOML text of plain values, for the files the daemon writes for itself or a user to read
back with :mod:`tomllib` (a capture bundle's ``manifest.toml``, a validation
``capture.toml``, a generated configuration's tables).

Strings are TOML basic strings with every character TOML forbids raw escaped (quote,
backslash, the C0 controls and DEL; TOML 1.0.0, "String"); every other character, including
those beyond the Basic Multilingual Plane, is written as itself (the files are UTF-8).
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

_NAMED_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n",
                  "\f": "\\f", "\r": "\\r"}
_ESCAPES = str.maketrans({**{chr(c): f"\\u{c:04X}" for c in (*range(0x20), 0x7F)},
                          **_NAMED_ESCAPES})


def toml_string(s: str) -> str:
    """``s`` as a TOML basic string (quotes included)."""
    return '"' + s.translate(_ESCAPES) + '"'


def toml_value(v: Any) -> str:
    """``v`` as an inline TOML value: bool, integer, float (``inf``/``nan`` included), string,
    list or tuple (array), mapping (inline table, keys bare); anything else as the string of
    its ``str()`` (e.g. a path)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        return repr(float(v))  # 'inf', '-inf' and 'nan' are TOML floats too
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return toml_string(str(v))
