"""default.toml documents every key the configuration accepts, with its default and bounds.

The keys are read from the parsers themselves: :func:`grassd.daemon.core.config.schema.recording`
collects every schema a table is checked against while the embedded default, with every optional
section added, is parsed. A key is documented where default.toml first writes it, set
(``key = value``) or commented (``# key = value``), with the comment after the value (and its
indented continuation lines) saying its bounds; a value written there that is not the key's
default (the dataclass's, the one a file without the key gets) says ``default X``, so the two
cannot drift apart unnoticed.
"""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import dataclass
from typing import Any

import pytest

from grassd.daemon.core.config import schema
from grassd.daemon.core.config.settings import (
    default_config_text,
    load_default_config,
    parse_config,
)
from grassd.daemon.core.errors import ConfigError

#: The optional sections default.toml leaves out (they switch features on), with what each
#: needs to be valid, so that parsing the default with them walks every table's schema.
EVERY_SECTION = '''
[audience]
polygon = [[-2.0, -4.0], [2.0, -4.0], [2.0, -1.5]]
h_cm = [150, 180]
[capture]
camera = "http://192.0.2.1"
[measure]
[content]
[content.sacn]
[content.artnet]
port = 6455
[[content.playlist]]
file = "pictures/wave.gif"
'''

#: A key's dotted path without array indices: ("light", "modbus", "port").
KeyPath = tuple[str, ...]


def accepted_keys(text: str) -> dict[KeyPath, schema.Field]:
    """Every key (dotted path, array indices left out) the parsers accept, with its field; the
    tables themselves are not keys. Fails when a table the schemas accept was never walked."""
    with schema.recording() as seen:
        parse_config(text + EVERY_SECTION, source="<default.toml + every section>")
    keys: dict[KeyPath, schema.Field] = {}
    for table, fields in seen.items():
        for name, field in fields.items():
            path = table + (name,)
            if path in seen:
                continue
            assert field.kind is not dict, (
                f"[{'.'.join(path)}] is a table no parse walked: add it to EVERY_SECTION")
            keys[path] = field
    return keys


@dataclass(frozen=True)
class Written:
    """One ``key = value`` line of default.toml, set or commented out."""

    path: KeyPath
    value: Any
    set: bool
    doc: str  # the comment after the value, with its continuation lines
    line: int


_CONTINUATION = re.compile(r"^(\s+#|#\s+#)")


def written_keys(text: str) -> list[Written]:
    """The ``key = value`` lines of ``text``: set ones, and commented ones (``# key = value``)
    in the table of the last header above them, set or commented (``# [tables]``)."""
    lines = text.splitlines()
    out: list[Written] = []
    table: KeyPath = ()
    for i, raw in enumerate(lines):
        commented = raw.lstrip().startswith("#")
        body = (raw.lstrip()[1:] if commented else raw).strip()
        if not body or body.startswith("#"):
            continue
        try:
            parsed = tomllib.loads(body)
        except tomllib.TOMLDecodeError:
            continue  # prose
        if body.startswith("["):
            table = _header_path(parsed)
            continue
        ((key, value),) = parsed.items()
        doc = next((body[p + 1:] for p in (m.start() for m in re.finditer("#", body))
                    if _parses_to(body[:p], parsed)), "")
        j = i + 1
        while j < len(lines) and _CONTINUATION.match(lines[j]):
            doc += " " + lines[j].strip().lstrip("#").strip().lstrip("#").strip()
            j += 1
        out.append(Written(table + (key,), value, not commented, doc, i + 1))
    return out


def _header_path(parsed: Any) -> KeyPath:
    path: list[str] = []
    while parsed:
        if isinstance(parsed, list):
            parsed = parsed[-1]
            continue
        ((name, parsed),) = parsed.items()
        path.append(name)
    return tuple(path)


def _parses_to(text: str, want: dict[str, Any]) -> bool:
    try:
        return tomllib.loads(text) == want
    except tomllib.TOMLDecodeError:
        return False


def set_keys(data: dict[str, Any], tables: set[KeyPath], at: KeyPath = ()) -> set[KeyPath]:
    """The keys the parsed TOML ``data`` sets (array indices left out)."""
    out: set[KeyPath] = set()
    for name, value in data.items():
        path = at + (name,)
        if path in tables and isinstance(value, dict):
            out |= set_keys(value, tables, path)
        elif path in tables and isinstance(value, list):
            for item in value:
                out |= set_keys(item, tables, path)
        else:
            out.add(path)
    return out


def toml_value(v: Any) -> str:
    """``v`` as default.toml writes it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return repr(v)


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def bounds_texts(check: Any) -> list[tuple[str, ...]]:
    """What the comment of a key with ``check`` must say: each entry's alternatives, one of
    which must appear (no entry: a check whose bounds are written in words)."""
    if isinstance(check, schema.Between):
        return [(f"{_number(check.lo)}..{_number(check.hi)}",)]
    if isinstance(check, schema.OneOf):
        return [(toml_value(c),) for c in check.choices]
    if check is schema.positive:
        return [("> 0",)]
    if check is schema.non_negative:
        return [(">= 0", "> 0")]
    return []


def _same(a: Any, b: Any) -> bool:
    """Whether a written value is a default (TOML arrays are read as lists, defaults may be
    tuples)."""
    def norm(v: Any) -> Any:
        return list(v) if isinstance(v, tuple) else v

    return norm(a) == norm(b)


def problems(text: str) -> list[str]:
    """What default.toml ``text`` fails to document, one message per key and rule."""
    keys = accepted_keys(text)
    writes = written_keys(text)
    out = []
    for w in writes:
        if w.path not in keys:
            out.append(f"line {w.line}: {'.'.join(w.path)} is no key the configuration accepts")
    first = {}
    for w in writes:
        first.setdefault(w.path, w)
    tables = {p[:n] for p in keys for n in range(1, len(p))}
    for path in set_keys(tomllib.loads(text), tables) - {w.path for w in writes if w.set}:
        out.append(f"{'.'.join(path)} is set but the test's line scan missed it")
    ctx = schema.Context("", "<default.toml>")
    for path, field in keys.items():
        name = ".".join(path)
        w = first.get(path)
        if w is None:
            out.append(f"{name}: neither set nor named in a comment")
            continue
        try:
            value = schema.check_type(ctx, path, w.value, field.kind, field.hint)
            msg = field.check(value) if field.check is not None else None
        except ConfigError as exc:
            msg = str(exc)
        if msg:
            out.append(f"line {w.line}: {name} = {w.value!r} is out of bounds: {msg}")
        for alternatives in bounds_texts(field.check):
            if not any(a in w.doc for a in alternatives):
                out.append(f"line {w.line}: {name}: the comment does not give the bounds "
                           f"({' or '.join(alternatives)})")
        if (field.default is not schema.MISSING and field.default is not None
                and not _same(w.value, field.default)
                and f"default {toml_value(field.default)}" not in w.doc):
            out.append(f"line {w.line}: {name} = {toml_value(w.value)} is not the default "
                       f"{toml_value(field.default)}, and its comment does not say "
                       f"'default {toml_value(field.default)}'")
    return out


def test_default_toml_documents_every_key_with_its_default_and_bounds():
    found = problems(default_config_text())
    assert not found, f"{len(found)} problems in default.toml:\n" + "\n".join(found)


def test_the_keys_come_from_the_parsers():
    keys = accepted_keys(default_config_text())
    assert {("light", "settle_s"), ("tables", "eye"), ("calibration", "replicates"),
            ("measure", "deadline_s"), ("simulation", "lengths"),
            ("content", "artnet", "net"), ("content", "playlist", "hours"),
            ("display", "pixel", "green_srgb")} <= set(keys)
    assert ("light",) not in keys and ("content", "sacn") not in keys


@pytest.mark.parametrize("key", ["settle_s", "replicates", "connect_timeout_s", "deadline_s",
                                 "green_srgb", "hours"])
def test_a_key_taken_out_of_default_toml_is_found(key):
    text = default_config_text()
    lines = [ln for ln in text.splitlines()
             if not re.match(rf"^\s*#?\s*{key}\s*=", ln)]
    assert len(lines) < len(text.splitlines())
    found = problems("\n".join(lines) + "\n")
    assert any(f".{key}: neither set nor named" in p for p in found), found


def test_a_wrong_default_or_missing_bound_is_found():
    text = default_config_text()
    drifted = re.sub(r"(?m)^replicates = 8", "replicates = 9", text)
    assert drifted != text
    assert any("calibration.replicates = 9 is not the default 8" in p
               for p in problems(drifted))
    unbounded = re.sub(r"(?m)^(# fps = 30\s+#.*?)\(1\.\.60\)", r"\1", text)
    assert unbounded != text
    assert any("content.fps: the comment does not give the bounds (1..60)" in p
               for p in problems(unbounded))


def test_the_keys_set_to_their_default_can_be_left_out():
    """A set value equal to its default is only documentation: the configuration without
    those lines is the same as the embedded default's."""
    text = default_config_text()
    keys = accepted_keys(text)
    lines = text.splitlines()
    dropped = 0
    for w in written_keys(text):
        field = keys[w.path]
        if w.set and field.default not in (schema.MISSING, None) and _same(w.value,
                                                                            field.default):
            lines[w.line - 1] = ""
            dropped += 1
    assert dropped > 30
    bare = parse_config("\n".join(lines) + "\n", source="<embedded default.toml>")
    assert bare == load_default_config()
