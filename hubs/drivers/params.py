"""A driver's parameters: typed, every unknown or mistyped key an error that names the key.

Each driver declares its parameters as a msgspec Struct deriving from `DriverParams`
(which adds the reconnect backoff every driver takes, and rejects unknown keys).
`convert_params` turns a device's table from hubs.toml into that Struct, or raises
`ParamError` naming the parameter; `hubs.factory` adds file, line, hub and resource.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

import msgspec

from .reconnect import Backoff

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]
Port = Annotated[int, msgspec.Meta(ge=0, le=65535)]

S = TypeVar("S", bound=msgspec.Struct)


class DriverParams(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, frozen=True):
    """What every driver accepts: its reconnect backoff (s)."""

    reconnect_min: Positive = 0.2
    reconnect_max: Positive = 5.0
    reconnect_factor: Annotated[float, msgspec.Meta(ge=1)] = 2.0
    reconnect_jitter: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.2

    def backoff(self) -> Backoff:
        return Backoff(initial=self.reconnect_min, maximum=self.reconnect_max, factor=self.reconnect_factor,
                       jitter=self.reconnect_jitter)

    def options(self, *, leave_out: tuple[str, ...] = ()) -> dict[str, Any]:
        """A driver's keyword arguments: each of its own parameters by name (but `leave_out`), and the
        reconnect settings as one `backoff`."""
        own = {f.name: getattr(self, f.name) for f in msgspec.structs.fields(self)
               if not f.name.startswith("reconnect_") and f.name not in leave_out}
        return {**own, "backoff": self.backoff()}


class ParamError(ValueError):
    """A bad driver parameter; `key` is its (dotted) name, None when it concerns the whole table."""

    def __init__(self, key: str | None, message: str, *, missing: bool = False) -> None:
        self.key = key
        self.message = message
        self.missing = missing  # a required parameter is absent
        super().__init__(f"parameter {key!r}: {message}" if key else message)


def require_strict(params_type: type[msgspec.Struct]) -> None:
    """TypeError unless `params_type` rejects unknown keys (a misspelt parameter must not pass silently)."""
    if not params_type.__struct_config__.forbid_unknown_fields:
        raise TypeError(f"{params_type.__name__}: a driver's parameter Struct must be declared with "
                        f"forbid_unknown_fields=True (or derive from DriverParams)")


def invalid(key: str, message: str) -> ValueError:
    """For a Struct's `__post_init__`: an error that `convert_params` reports under `key`."""
    return ValueError(f"{message} - at `$.{key}`")


_AT = re.compile(r"^(?P<text>.*) - at `\$(?P<path>[^`]*)`$", re.DOTALL)
_UNKNOWN = re.compile(r"^Object contains unknown field `(?P<key>[^`]+)`$")
_MISSING = re.compile(r"^Object missing required field `(?P<key>[^`]+)`$")


def _dotted(path: str) -> str:
    """msgspec's `$.zones.robot[0]` -> `zones.robot`: a key that hubs.toml has a line for."""
    return ".".join(p for p in re.sub(r"\[[^\]]*\]", "", path).split(".") if p)


def param_names(params_type: type[msgspec.Struct]) -> list[str]:
    return sorted(f.encode_name for f in msgspec.structs.fields(params_type))


def convert_params(params_type: type[S], raw: Mapping[str, Any]) -> S:
    """`raw` as `params_type`; ParamError naming the parameter when a key is unknown, missing or bad."""
    try:
        return msgspec.convert(dict(raw), params_type)
    except msgspec.ValidationError as exc:
        text, path = str(exc), ""
        at = _AT.match(text)
        if at:
            text, path = at.group("text"), _dotted(at.group("path"))
        unknown, missing = _UNKNOWN.match(text), _MISSING.match(text)
        if unknown and not path:
            raise ParamError(unknown.group("key"), f"unknown parameter (this driver's parameters: "
                                                   f"{', '.join(param_names(params_type))})") from None
        if unknown:
            raise ParamError(f"{path}.{unknown.group('key')}", "unknown key") from None
        if missing:
            key = f"{path}.{missing.group('key')}" if path else missing.group("key")
            raise ParamError(key, "missing (required)", missing=True) from None
        if path:
            found = raw.get(path.split(".", 1)[0]) if "." not in path else None
            shown = f" (found {found!r})" if found is not None else ""
            raise ParamError(path, f"{text}{shown}") from None
        raise ParamError(None, text) from None
