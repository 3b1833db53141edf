"""Reading a device's ``hubs.toml`` parameters with errors that name the parameter."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def require(params: Mapping[str, Any], name: str) -> Any:
    """The parameter ``name``; ValueError naming it when it is missing."""
    if name not in params:
        raise ValueError(f"missing parameter {name!r}")
    return params[name]
