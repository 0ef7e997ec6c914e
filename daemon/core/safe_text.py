"""Text from outside made safe for one line of output.

A bundle's name is chosen by whoever writes the inbox: it may hold a newline, a carriage
return, ANSI escapes, bidi overrides, bytes that are not UTF-8 (a file name decodes them to
lone surrogates) or be very long. Wherever such text reaches a log line, an sd_notify
``STATUS=``, an alert, a metric label or the status page it goes through :func:`one_line`
first: what could break the line, forge a second record or steer a terminal is written as a
visible escape instead (``\\n``, ``\\x1b``, ``\\u202e``), and a long text is cut.

This module imports nothing of grassd, so every layer (store, runtime, monitoring) may use it.
"""

from __future__ import annotations

import re

#: characters a name keeps for one line by default (a file name has at most 255 bytes)
MAX_NAME_CHARS = 200

#: C0 and C1 controls and DEL; the Unicode line and paragraph separators; the invisible
#: format characters that reorder or hide text (bidi marks, embeddings, overrides and
#: isolates, zero-width characters, word joiner, BOM, interlinear annotation); lone
#: surrogates (undecodable bytes of a file name, or text that cannot be encoded as UTF-8)
_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u180e\u200b-\u200f\u2028-\u202e"
                     "\u2060-\u206f\ufeff\ufff9-\ufffb\ud800-\udfff]")
_SHORT = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(ch: str) -> str:
    """The visible escape of one unsafe character."""
    if ch in _SHORT:
        return _SHORT[ch]
    code = ord(ch)
    if code < 0x100:
        return f"\\x{code:02x}"
    if 0xDC80 <= code <= 0xDCFF:  # a byte that was not UTF-8 (surrogateescape)
        return f"\\x{code - 0xDC00:02x}"
    return f"\\u{code:04x}"


def one_line(text: object, max_chars: int | None = MAX_NAME_CHARS) -> str:
    """``text`` (``str()`` of anything else) as one line of printable text: control,
    line-separator and invisible format characters and lone surrogates become visible
    escapes (module docstring); backslashes stay as they are. With ``max_chars`` (None: no
    limit) a longer result is cut at a character boundary and ends in
    ``...(N more characters)``.

    >>> one_line("b1\\n<3>forged\\x1b[31m")
    'b1\\\\n<3>forged\\\\x1b[31m'
    >>> one_line("x" * 300, max_chars=5)
    'xxxxx...(295 more characters)'
    """
    s = text if isinstance(text, str) else str(text)
    out = _UNSAFE.sub(lambda m: _escape(m.group()), s)
    if max_chars is None or len(out) <= max_chars:
        return out
    kept: list[str] = []
    n = 0
    for i, ch in enumerate(s):
        piece = _escape(ch) if _UNSAFE.match(ch) else ch
        if n + len(piece) > max_chars:
            return "".join(kept) + f"...({len(s) - i} more characters)"
        kept.append(piece)
        n += len(piece)
    return "".join(kept)  # not reached: the escaped text was longer than max_chars


_SURROGATE = re.compile("[\ud800-\udfff]")


def storable(text: str) -> str:
    """``text`` made encodable as UTF-8 (for a database, a file, JSON): lone surrogates (the
    undecodable bytes of a file name, or a ``\\ud800`` escape in JSON) become visible escapes
    as in :func:`one_line`; everything else, line breaks included, is kept.

    >>> storable("bad" + bytes([0xff]).decode("utf-8", "surrogateescape") + "name\\n")
    'bad\\\\xffname\\n'
    """
    return _SURROGATE.sub(lambda m: _escape(m.group()), text)
