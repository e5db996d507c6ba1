"""Where each key of a TOML text is written: :func:`key_lines` (key path -> line) and
:func:`key_parts` (a dotted key's parts), for error messages that name a file's line
(scene, study and parameter files)."""

from __future__ import annotations

import re
import tomllib

from .spec import KeyPath

_PART = r'(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|\'[^\']*\')'
_KEY = rf"{_PART}(?:\s*\.\s*{_PART})*"
_TABLE_LINE = re.compile(rf"^\[\[?\s*({_KEY})\s*\]\]?")
_KEY_LINE = re.compile(rf"^({_KEY})\s*=(.*)$")


def key_parts(key: str) -> KeyPath:
    """Split a TOML key (``a."b.c"``) into its parts, unquoted.

    >>> key_parts('study.factors."aps.A_p"')
    ('study', 'factors', 'aps.A_p')
    """
    return tuple(
        tomllib.loads(f"k = {p}")["k"] if p[0] in "\"'" else p for p in re.findall(_PART, key)
    )


def _open_brackets(value: str) -> tuple[int, str | None]:
    """Bracket depth left open by ``value`` and an unclosed multi-line string delimiter."""
    depth, i, quote = 0, 0, None
    while i < len(value):
        if quote:
            if value.startswith(quote, i) and (len(quote) == 3 or value[i - 1] != "\\"):
                i, quote = i + len(quote), None
                continue
        elif value.startswith(('"""', "'''"), i):
            quote = value[i : i + 3]
            i += 3
            continue
        elif value[i] in "\"'":
            quote = value[i]
        elif value[i] == "#":
            break
        elif value[i] in "[{":
            depth += 1
        elif value[i] in "]}":
            depth -= 1
        i += 1
    return depth, quote if quote and len(quote) == 3 else None


def key_lines(text: str) -> dict[KeyPath, int]:
    """Map each table and key path of a TOML text to the line (1-based) defining it.

    tomllib reports no positions, so this scans the text: table headers set the current
    table, ``key = value`` lines add a key under it. Values spanning several lines
    (arrays, inline tables, multi-line strings) are skipped over.
    """
    lines: dict[KeyPath, int] = {}
    table: KeyPath = ()
    depth, quote = 0, None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if quote:
            if quote in line:
                quote = None
            continue
        if depth > 0:
            depth += _open_brackets(line)[0]
            continue
        if match := _TABLE_LINE.match(line):
            table = key_parts(match[1])
            path = table
        elif match := _KEY_LINE.match(line):
            path = table + key_parts(match[1])
            depth, quote = _open_brackets(match[2])
        else:
            continue
        for k in range(1, len(path) + 1):  # a.b defines a too, if not yet defined
            lines.setdefault(path[:k], lineno)
    return lines
