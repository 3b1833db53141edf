"""The Zenoh config of a site router: an eclipse-zenoh session in `mode: router`.

There is no `zenohd` binary here: a router is a session of the same library opened in router
mode, which routes between its clients and links to the other routers it is told to connect to
(router-to-router links are ordinary links). As for every statehub process (common/bus/zenoh_config.py):
multicast scouting off (routers and stations are named, never discovered), explicit endpoints, a
link lease so that a router notices a frozen client, and a dead client's liveliness tokens vanish,
within about the lease.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

import zenoh

from common.bus.zenoh_config import DEFAULT_MAX_MESSAGE_BYTES, KEEP_ALIVES_PER_LEASE, TlsSettings, ZenohConfig
from common.line.config import LineConfig

ROUTER_MODE = "router"


def router_zenoh_config(listen: Sequence[str], connect: Sequence[str], lease_ms: int, *,
                        tls: TlsSettings | None = None) -> ZenohConfig:
    """A router listening on `listen` and linking to the routers on `connect`."""
    if not listen:
        raise ValueError("a router needs at least one listen endpoint")
    if tls is not None and any(not e.startswith("tls/") for e in (*listen, *connect)):
        raise ValueError(f"with TLS every endpoint must be tls/: {', '.join((*listen, *connect))}")
    settings: dict[str, Any] = {
        "mode": ROUTER_MODE,
        "listen/endpoints": list(listen),
        "connect/endpoints": list(connect),
        "scouting/multicast/enabled": False,
        # Routers learn of each other only through the links line.toml names.
        "scouting/gossip/enabled": False,
        "transport/link/tx/lease": lease_ms,
        "transport/link/tx/keep_alive": KEEP_ALIVES_PER_LEASE,
        "transport/link/rx/max_message_size": DEFAULT_MAX_MESSAGE_BYTES,
        # A router started before the one it links to keeps trying, and so does one whose neighbour restarted.
        "connect/exit_on_failure": False,
        "connect/retry": {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2},
        # Nothing of the stations is stored at the router: it only routes.
        "timestamping/enabled": False,
    }
    if tls is not None:
        settings.update(tls.settings())
    config = zenoh.Config()
    for key, value in settings.items():
        config.insert_json5(key, json.dumps(value))
    return config


def line_router_config(line: LineConfig, name: str, tls: TlsSettings | None = None) -> ZenohConfig:
    """Router `name` of line.toml."""
    router = line.routers.get(name)
    if router is None:
        raise KeyError(f"{line.path}: no router {name!r} (routers: {', '.join(line.routers)})")
    return router_zenoh_config(router.listen, router.connect, line.lease_ms, tls=tls)


def describe(settings: Mapping[str, Sequence[str]]) -> str:
    return "; ".join(f"{k} {', '.join(v) or 'none'}" for k, v in settings.items())
