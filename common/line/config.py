"""line.toml: a line of stations, the Zenoh routers between them and the products' route (DESIGN.md §14).

    [line]
    name = "demo"                       # the line controller's keys: line/{name}/...
    db = "var/line.sqlite"              # the line controller's SQLite (relative to line.toml)
    router = "r1"                       # the router the line controller connects to
    lease_ms = 1000                     # the link lease of every router and of the line controller

    [security]                          # optional: the site's links
    mode = "insecure"                   # or "tls": the site's CA, access control at the routers
    certs = "certs"                     # the site's certificate directory (ca.crt, NAME.crt/.key)

    [routers.r1]
    listen = ["tcp/127.0.0.1:7501"]
    connect = []                        # other routers this one links to
    [routers.r2]
    listen = ["tcp/127.0.0.1:7502"]
    connect = ["tcp/127.0.0.1:7501"]

    [stations.s1]
    config = "s1/hubs.toml"             # the station's own hubs.toml (relative to line.toml)
    router = "r1"                       # the router its processes are clients of
    variant = "default"                 # the variant of its model a line product is at this station

    [route]
    stations = ["s1", "s2", "s3"]       # every product visits them in this order

Every problem is reported with file, line and key (common/config/errors.py), all at once. The
stations' hubs.toml files are read only by `load_line_stations`: checking line.toml needs none.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.config.errors import ConfigError, ConfigProblem, toml_problem, toml_type
from common.config.keylines import KeyLines
from common.config.modes import SecurityMode, words

SECTIONS = ("line", "security", "routers", "stations", "route")


@dataclass(frozen=True)
class RouterConfig:
    name: str
    listen: tuple[str, ...]
    connect: tuple[str, ...]


@dataclass(frozen=True)
class LineStation:
    name: str  # the line's name for it; its keys are those of its hubs.toml [station] name
    config: Path  # its hubs.toml, absolute
    router: str
    variant: str


@dataclass(frozen=True)
class SiteSecurity:
    mode: SecurityMode
    certs: Path | None  # None: insecure


@dataclass(frozen=True)
class LineConfig:
    path: Path
    name: str
    db: Path
    router: str  # the line controller's router
    lease_ms: int
    security: SiteSecurity
    routers: Mapping[str, RouterConfig]
    stations: Mapping[str, LineStation]
    route: tuple[str, ...]

    def router_endpoints(self, router: str) -> list[str]:
        """Where a client of `router` connects: its listeners."""
        return list(self.routers[router].listen)

    def next_station(self, station: str) -> str | None:
        """The station after `station` on the route; None after the last."""
        index = self.route.index(station)
        return self.route[index + 1] if index + 1 < len(self.route) else None


class _Problems:
    def __init__(self, file: str, text: str) -> None:
        self.file = file
        self.lines = KeyLines(text)
        self.found: list[ConfigProblem] = []

    def add(self, path: tuple[str, ...], message: str) -> None:
        self.found.append(ConfigProblem(self.file, self.lines.line_of(path), ".".join(path), message))

    def table(self, value: object, path: tuple[str, ...]) -> dict[str, Any]:
        if isinstance(value, dict):
            return value
        self.add(path, f"must be a table, not {toml_type(value)}")
        return {}

    def keys(self, table: Mapping[str, Any], path: tuple[str, ...], known: tuple[str, ...]) -> None:
        for key in table:
            if key not in known:
                self.add((*path, key), f"unknown key (known keys: {', '.join(known)})")

    def string(self, table: Mapping[str, Any], path: tuple[str, ...], key: str, default: str | None = None) -> str:
        value = table.get(key, default)
        if value is None:
            self.add(path, f"missing key {key!r}")
            return ""
        if not isinstance(value, str) or not value:
            self.add((*path, key), f"must be a non-empty string, not {toml_type(value)} {value!r}")
            return ""
        return value

    def strings(self, table: Mapping[str, Any], path: tuple[str, ...], key: str) -> tuple[str, ...]:
        value = table.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            self.add((*path, key), f"must be an array of strings, not {toml_type(value)} {value!r}")
            return ()
        return tuple(value)


def load_line(path: str | Path) -> LineConfig:
    """Read and check line.toml. Raises ConfigError (every problem with file, line and key) or OSError."""
    path = Path(path)
    return parse_line(path.read_text(encoding="utf-8"), path)


def parse_line(text: str, path: Path) -> LineConfig:
    file = str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([toml_problem(file, str(exc))]) from None
    p = _Problems(file, text)
    for key in data:
        if key not in SECTIONS:
            p.add((key,), f"unknown section (known: {', '.join(SECTIONS)})")
    base = path.parent

    if "line" not in data:
        p.add(("line",), "missing section [line] (its name, db and router)")
    line = p.table(data.get("line", {}), ("line",))
    p.keys(line, ("line",), ("name", "db", "router", "lease_ms"))
    name = p.string(line, ("line",), "name") if "line" in data else ""
    db = p.string(line, ("line",), "db", "var/line.sqlite")
    lease_ms = line.get("lease_ms", 1000)
    if not isinstance(lease_ms, int) or isinstance(lease_ms, bool) or lease_ms < 100:
        p.add(("line", "lease_ms"), f"must be an integer >= 100 (milliseconds), not {lease_ms!r}")
        lease_ms = 1000

    security_table = p.table(data.get("security", {}), ("security",))
    p.keys(security_table, ("security",), ("mode", "certs"))
    mode_word = security_table.get("mode", SecurityMode.INSECURE.value)
    mode = SecurityMode.INSECURE
    if mode_word not in words(SecurityMode):
        p.add(("security", "mode"), f"unknown mode {mode_word!r} (expected one of: {', '.join(words(SecurityMode))})")
    else:
        mode = SecurityMode(mode_word)
    certs: Path | None = None
    if mode is SecurityMode.TLS:
        certs_word = p.string(security_table, ("security",), "certs")
        certs = (base / Path(certs_word).expanduser()) if certs_word else None

    routers: dict[str, RouterConfig] = {}
    for router_name, value in p.table(data.get("routers", {}), ("routers",)).items():
        where = ("routers", router_name)
        table = p.table(value, where)
        p.keys(table, where, ("listen", "connect"))
        listen, connect = p.strings(table, where, "listen"), p.strings(table, where, "connect")
        if not listen:
            p.add(where, "a router needs at least one `listen` endpoint (its stations connect to it)")
        routers[router_name] = RouterConfig(router_name, listen, connect)
    if not routers:
        p.add(("routers",), "a line needs at least one router ([routers.NAME])")

    stations: dict[str, LineStation] = {}
    for station_name, value in p.table(data.get("stations", {}), ("stations",)).items():
        where = ("stations", station_name)
        table = p.table(value, where)
        p.keys(table, where, ("config", "router", "variant"))
        config = p.string(table, where, "config")
        router = p.string(table, where, "router")
        if router and routers and router not in routers:
            p.add((*where, "router"), f"no router {router!r} (routers: {', '.join(routers)})")
        config_path = base / config if config else base
        if config and not config_path.is_file():
            p.add((*where, "config"), f"no file {config_path}")
        stations[station_name] = LineStation(station_name, config_path, router,
                                             p.string(table, where, "variant", "default"))

    line_router = p.string(line, ("line",), "router") if "line" in data else ""
    if line_router and routers and line_router not in routers:
        p.add(("line", "router"), f"no router {line_router!r} (routers: {', '.join(routers)})")

    route_table = p.table(data.get("route", {}), ("route",))
    p.keys(route_table, ("route",), ("stations",))
    route = p.strings(route_table, ("route",), "stations")
    if not route:
        p.add(("route",), "missing key 'stations': the stations every product visits, in order")
    for index, station_name in enumerate(route):
        if station_name not in stations:
            p.add(("route", "stations"), f"no station {station_name!r} (stations: {', '.join(stations) or 'none'})")
        if station_name in route[:index]:
            p.add(("route", "stations"), f"station {station_name!r} twice: a product visits a station once")
    if p.found:
        raise ConfigError(p.found)
    return LineConfig(path=path, name=name, db=base / db, router=line_router, lease_ms=lease_ms,
                      security=SiteSecurity(mode, certs), routers=routers, stations=stations, route=route)
