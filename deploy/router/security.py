"""A router's TLS files and access control ([security] mode = "tls" of line.toml).

The router enforces, on every link, the access control of every station of the line (each derived from
the station's own hubs.toml, common/config/acl.py) under its holders' certificate names, plus:

* the line controller (certificate name LINE_CONTROLLER_NAME, also what `hubctl line up`'s overview
  presents): query each station's `ctl/orders`, and subscribe to and query its `ctl/status`, nothing
  else: it cannot command a resource;
* the other routers: anything, both ways. A message another router forwards was checked on its way in
  at the router its sender is a client of: each router checks its own clients.

Holder names must be unique across the line (a station's `ctl` and another's `ctl` would be one subject):
`check_unique_names` says which clash.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from common.bus.zenoh_config import TlsSettings
from common.config.acl import ALL_MESSAGES, Grant, access_control
from common.config.hubs_toml import StationConfig, load_station
from common.config.modes import SecurityMode
from common.config.security import Identity, SecurityError, roles_of, tls_files
from common.line.config import LineConfig
from common.model import Model
from common.wire.keys import Keys
from common.wire.orders import ORDERS_KEY

LINE_CONTROLLER_NAME = "line-controller"


def line_controller_grants(stations: Iterable[Keys]) -> list[Grant]:
    keys = list(stations)
    return [
        Grant(("query",), tuple(key for k in keys for key in (k.ctl(ORDERS_KEY), k.ctl("status")))),
        Grant(("declare_subscriber",), tuple(k.ctl("status") for k in keys)),
    ]


def check_unique_names(stations: Iterable[StationConfig], routers: Iterable[str]) -> None:
    seen: dict[str, str] = {name: "the line controller" for name in (LINE_CONTROLLER_NAME,)}
    seen.update({router: f"router {router}" for router in routers})
    for config in stations:
        for name in roles_of(config):
            holder = f"station {config.station.name}"
            if name in seen:
                raise SecurityError(f"{config.path}: the certificate name {name!r} is also {seen[name]}'s: with "
                                    f"[security] mode = \"tls\" every holder's name must be unique on the line "
                                    f"(rename it: [controller] name, a [hubs.NAME] table, [security] operators "
                                    f"or [overview] name)")
            seen[name] = holder


def _rules(prefix: str, grants: Iterable[Grant], flow: str) -> list[dict[str, Any]]:
    return [{"id": f"{prefix}-{i}", "messages": list(g.messages), "flows": [flow], "permission": "allow",
             "key_exprs": list(g.keys)} for i, g in enumerate(grants)]


def line_access_control(stations: Iterable[tuple[StationConfig, Model]], routers: Iterable[str]) -> dict[str, Any]:
    """The `access_control` section of a router: every station's, the line controller's, the routers'."""
    stations = list(stations)
    routers = list(routers)
    check_unique_names((c for c, _ in stations), routers)
    rules: list[dict[str, Any]] = _rules("to-all", [Grant(ALL_MESSAGES, ("**",))], "egress")
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for config, model in stations:
        station = access_control(config, model)
        prefix = config.station.name
        renamed = {r["id"]: f"{prefix}:{r['id']}" for r in station["rules"]}
        rules += [{**r, "id": renamed[r["id"]]} for r in station["rules"] if r["flows"] == ["ingress"]]
        subjects += [{**s, "id": f"{prefix}:{s['id']}"} for s in station["subjects"]]
        policies += [{"id": f"{prefix}:{p['id']}", "rules": [renamed[r] for r in p["rules"]],
                      "subjects": [f"{prefix}:{s}" for s in p["subjects"]]}
                     for p in station["policies"] if p["id"] != "station-receives"]
    own = _rules("from-line-controller", line_controller_grants(c.keys for c, _ in stations), "ingress")
    rules += own
    subjects.append({"id": "line-controller", "cert_common_names": [LINE_CONTROLLER_NAME]})
    policies.append({"id": "line-controller-sends", "rules": [r["id"] for r in own], "subjects": ["line-controller"]})
    between = _rules("from-router", [Grant(ALL_MESSAGES, ("**",))], "ingress")
    rules += between
    if routers:
        subjects.append({"id": "routers", "cert_common_names": routers})
        policies.append({"id": "routers-send", "rules": [r["id"] for r in between], "subjects": ["routers"]})
    policies.append({"id": "everyone-receives", "rules": ["to-all-0"], "subjects": [s["id"] for s in subjects]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def router_tls(line: LineConfig, name: str, certs: Path | None = None) -> TlsSettings | None:
    """Router `name`'s TLS files and the line's access control; None on an insecure line."""
    if line.security.mode is not SecurityMode.TLS:
        return None
    directory = certs or line.security.certs
    if directory is None:
        raise SecurityError(f"{line.path}: [security] certs: no certificate directory for router {name}")
    files = tls_files(directory, Identity(name, "controller"))
    stations = [load_station(s.config) for s in line.stations.values()]
    return TlsSettings(files.root_ca, files.certificate, files.private_key,
                       line_access_control(stations, line.routers), verify_names=False)


def peer_access_control(routers: Iterable[str]) -> dict[str, Any]:
    """What a client of the routers (the line controller) enforces on its link: the routers may send it
    anything (they checked it on its way in), no one else reaches it."""
    rules = _rules("router", [Grant(ALL_MESSAGES, ("**",))], "ingress") + \
        _rules("to-router", [Grant(ALL_MESSAGES, ("**",))], "egress")
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": [{"id": "routers", "cert_common_names": list(routers)}],
            "policies": [{"id": "routers", "rules": [r["id"] for r in rules], "subjects": ["routers"]}]}
