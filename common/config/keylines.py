"""Where a key is written in a TOML file: tomllib does not keep line numbers, errors need them."""

from __future__ import annotations

import re
from collections.abc import Iterable

_KEY_PART = r'(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|\'[^\']*\')'
_DOTTED_KEY = rf"{_KEY_PART}(?:\s*\.\s*{_KEY_PART})*"
_HEADER = re.compile(rf"^\s*\[\[?\s*({_DOTTED_KEY})\s*\]\]?\s*(?:#.*)?$")
_ASSIGN = re.compile(rf"^\s*({_DOTTED_KEY})\s*=")
_INLINE_ASSIGN = re.compile(rf"[{{,]\s*({_DOTTED_KEY})\s*=")
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'')


def _split_key(text: str) -> tuple[str, ...]:
    parts = re.findall(_KEY_PART, text)
    return tuple(p[1:-1] if p[:1] in "\"'" else p for p in parts)


class KeyLines:
    """Line numbers of the keys and tables in TOML text (tomllib does not keep them).

    A line-based scan: good for the files people write (tables, `key = value`,
    inline tables on one line, multi-line arrays and strings)."""

    def __init__(self, text: str) -> None:
        self._explicit: dict[tuple[str, ...], int] = {}
        self._implicit: dict[tuple[str, ...], int] = {}
        table: tuple[str, ...] = ()
        in_multiline: str | None = None
        depth = 0  # open brackets of a multi-line array
        for number, line in enumerate(text.splitlines(), start=1):
            if in_multiline is not None:
                if line.count(in_multiline) % 2 == 1:
                    in_multiline = None
                continue
            if depth > 0:
                code = _STRING.sub('""', line).split("#", 1)[0]
                depth += code.count("[") - code.count("]")
                continue
            header = _HEADER.match(line)
            if header:
                table = _split_key(header.group(1))
                self._record(table, number)
                continue
            assign = _ASSIGN.match(line)
            if not assign:
                continue
            path = table + _split_key(assign.group(1))
            self._record(path, number)
            rest = line[assign.end():]
            for inner in _INLINE_ASSIGN.finditer(rest):
                self._explicit.setdefault(path + _split_key(inner.group(1)), number)
            for quote in ('"""', "'''"):
                if rest.count(quote) % 2 == 1:
                    in_multiline = quote
            code = _STRING.sub('""', rest).split("#", 1)[0]  # brackets inside strings do not count
            depth = max(0, code.count("[") - code.count("]"))

    def _record(self, path: tuple[str, ...], number: int) -> None:
        self._explicit.setdefault(path, number)
        for i in range(1, len(path)):
            self._implicit.setdefault(path[:i], number)

    def line_of(self, path: Iterable[str]) -> int | None:
        """The line of `path`, or of its longest written prefix."""
        path = tuple(path)
        while path:
            line = self._explicit.get(path) or self._implicit.get(path)
            if line:
                return line
            path = path[:-1]
        return None
