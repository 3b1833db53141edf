"""The operator page's parameters: the operator device's table in hubs.toml (less `type` and `mode`).

Checked like every driver's (hubs/drivers/params.py): an unknown, missing or mistyped key is an error
naming file, line and key (`hubctl config check`)."""

from __future__ import annotations

import ipaddress
from typing import Annotated

import msgspec

from hubs.drivers.nutrunner_mcp23017 import parse_pin
from hubs.drivers.params import DriverParams, Port, Positive, invalid

TOKEN_MIN_CHARS = 16  # a guessable token is no protection


class ButtonParams(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    """[... .button]: a pushbutton on an MCP23017 input."""

    bus: Annotated[int, msgspec.Meta(ge=0)] = 1  # /dev/i2c-<bus>
    address: Annotated[int, msgspec.Meta(ge=0x20, le=0x27)] = 0x21
    pin: str = "A0"
    active_low: bool = True  # wired to ground, the expander's pull-up on
    poll_s: Positive = 0.02


class OperatorPageParams(DriverParams, frozen=True, kw_only=True):
    host: str = "127.0.0.1"  # the address the page binds to ("0.0.0.0": every interface of the hub)
    port: Port = 8080
    instructions: str = ""  # the station's instruction table, `module:ATTRIBUTE`
    language: str = ""  # of the instructions; "" = the table's first
    badge_reader: str = ""  # the RFID resource whose `verified_m` says an operator is verified
    robot: str = ""  # the robot resource whose pose the page shows
    tokens: dict[str, str] = {}  # device name -> token for the confirm endpoint; the panel is one device too
    button: ButtonParams | None = None

    def __post_init__(self) -> None:
        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            if not self.host or any(c.isspace() or c == "/" for c in self.host):
                raise invalid("host", f"not an address to bind to: {self.host!r}") from None
        for device, token in self.tokens.items():
            if len(token) < TOKEN_MIN_CHARS:
                raise invalid(f"tokens.{device}", f"a token of at least {TOKEN_MIN_CHARS} characters (e.g. "
                                                  "`python -c 'import secrets; print(secrets.token_urlsafe())'`)")
        if self.button is not None:  # checked here, where the error can name the whole key
            try:
                parse_pin(self.button.pin)
            except ValueError as exc:
                raise invalid("button.pin", str(exc)) from None
