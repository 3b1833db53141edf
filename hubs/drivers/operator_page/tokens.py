"""Who may press the operator's button over HTTP: a token per device (the panel, a smartwatch, ...)."""

from __future__ import annotations

import hmac
from collections.abc import Mapping


class DeviceTokens:
    def __init__(self, tokens: Mapping[str, str]) -> None:
        self._tokens = dict(tokens)

    @property
    def required(self) -> bool:
        """No tokens configured: any client on the page's network may press (a station on one machine)."""
        return bool(self._tokens)

    def device_of(self, presented: str) -> str | None:
        """The device whose token `presented` is, None when it is nobody's (compared in constant time)."""
        found = None
        for device, token in self._tokens.items():
            if hmac.compare_digest(token.encode(), presented.encode()):
                found = device
        return found

    @staticmethod
    def from_header(authorization: str) -> str:
        """The token of an `Authorization: Bearer TOKEN` header, "" when there is none."""
        scheme, _, token = authorization.partition(" ")
        return token.strip() if scheme.lower() == "bearer" else ""
