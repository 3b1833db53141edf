"""`[overview]` of hubs.toml: where the supervisors' read-only overview page is served (controller/overview/).

    [overview]
    bind = "127.0.0.1:8470"   # HOST:PORT the page listens on (default: this machine only, port 8470)
    name = "overview"         # its certificate's common name in `tls` mode: the `viewer` role, which may only read

The section is optional; `hubctl overview --bind` overrides `bind`.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgspec

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8470
DEFAULT_BIND = f"{DEFAULT_HOST}:{DEFAULT_PORT}"


class OverviewConfig(msgspec.Struct, frozen=True):
    bind: str = DEFAULT_BIND
    name: str = "overview"


@dataclass(frozen=True)
class BindAddress:
    host: str
    port: int

    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else "[::1]" if self.host == "::" else self.host
        return f"http://{f'[{host}]' if ':' in host and not host.startswith('[') else host}:{self.port}/"


def parse_bind(text: str) -> BindAddress:
    """`HOST:PORT` (`[::1]:8470` for an IPv6 address); ValueError says what is wrong."""
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{text!r} is not HOST:PORT (e.g. {DEFAULT_BIND}, or 0.0.0.0:{DEFAULT_PORT} for every "
                         f"interface)")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"{text!r}: port {port!r} is not a number from 1 to 65535")
    if any(c.isspace() or c in "/[]" for c in host):
        raise ValueError(f"{text!r}: {host!r} is not a host name or address")
    return BindAddress(host, int(port))
