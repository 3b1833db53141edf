"""The badge readers running in this hub process, by resource: who is logged in, for the operator's page.

The station bus carries only whether an operator is verified (`rfid.verified_m`); the badge's name stays
with its reader. A page on the same hub as the reader (the reader mounted at the operator's panel) shows
the name too; a page on another hub shows "operator verified" from the bus alone."""

from __future__ import annotations

import weakref
from typing import Protocol


class BadgeReader(Protocol):
    @property
    def operator(self) -> str | None:
        """The logged-in operator's name, None when nobody is."""
        ...


_READERS: weakref.WeakValueDictionary[str, BadgeReader] = weakref.WeakValueDictionary()


def register(resource: str, reader: BadgeReader) -> None:
    _READERS[resource] = reader


def find(resource: str) -> BadgeReader | None:
    return _READERS.get(resource)
