"""Zenoh configuration of a statehub process: endpoints, scouting, lease, loopback.

Liveness: a peer that dies closes its TCP link and its tokens vanish at once; a peer
that freezes (SIGSTOP, a hung Pi) keeps the link open, so it is noticed only when its
transport lease expires. `zenoh_config` sets the lease (default 2 s) and the
keep-alive rate so that a frozen hub is declared gone within about the lease (the
lease a process declares is the one its neighbours apply to it). A peer whose link
closes, or that starts before the process it connects to, keeps retrying in the
background and comes back by itself.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import zenoh

from common.config.modes import NetworkMode, words

DEFAULT_LEASE_MS = 2000
# The largest message a process accepts on its links (zenoh's default is 1 GiB); a larger one is
# dropped by zenoh before it reaches Python. Far above any statehub message (a command is under 1 KB).
DEFAULT_MAX_MESSAGE_BYTES = 4 * 1024 * 1024
# Keep-alives per lease period. 4 is zenoh's default; with a 2 s lease a keep-alive
# goes out every 500 ms, so one lost keep-alive never expires a healthy link.
KEEP_ALIVES_PER_LEASE = 4

# A client's one link is to a router of the site's CA, which enforces the access control on its clients'
# links (deploy/router/security.py): the station's own rules name the station's holders only, so on the
# client they would deny the router, its only neighbour, everything.
CLIENT_ACCESS_CONTROL: dict[str, Any] = {"enabled": False}

ZenohConfig = zenoh.Config  # what `ZenohBus` opens; callers name the type without importing zenoh


@dataclass(frozen=True)
class TlsSettings:
    """Mutual TLS on every link, and the access control every link is checked against
    (common/config/security.py, common/config/acl.py). The same certificate serves listening and connecting."""

    root_ca: Path
    certificate: Path
    private_key: Path
    access_control: Mapping[str, Any] = field(default_factory=dict)
    # A connecting process checks that the listener's certificate names the host it dialled.
    verify_names: bool = True

    def settings(self) -> dict[str, Any]:
        cert, key = str(self.certificate), str(self.private_key)
        return {
            # No link of any other protocol: a plain tcp/ peer cannot even open a session.
            "transport/link/protocols": ["tls"],
            "transport/link/tls": {
                "root_ca_certificate": str(self.root_ca),
                "listen_certificate": cert, "listen_private_key": key,
                "connect_certificate": cert, "connect_private_key": key,
                "enable_mtls": True,  # a listener accepts only peers with a certificate of the station's CA
                "verify_name_on_connect": self.verify_names,
                "close_link_on_expiration": True,
            },
            "access_control": dict(self.access_control),
        }


class NetworkSettings(Protocol):
    """What `zenoh_config_for` needs; `common.config.hubs_toml.NetworkConfig` satisfies it (read only: it is frozen)."""

    @property
    def mode(self) -> str: ...
    @property
    def listen(self) -> Sequence[str]: ...
    @property
    def connect(self) -> Sequence[str]: ...
    @property
    def lease_ms(self) -> int: ...
    @property
    def max_message_bytes(self) -> int: ...


def zenoh_config(mode: NetworkMode | str = NetworkMode.PEER, listen: Iterable[str] = (), connect: Iterable[str] = (),
                 lease_ms: int = DEFAULT_LEASE_MS, *, gossip: bool = True,
                 tls: TlsSettings | None = None, max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> ZenohConfig:
    """A zenoh config for a statehub process.

    * `mode`: "peer" (direct links on loopback or the station LAN; the controller
      listens, hubs connect to it) or "client" (through zenoh routers given in `connect`).
    * `listen` / `connect`: zenoh endpoints (`tcp/127.0.0.1:7447`); an empty `listen`
      means no listener at all (zenoh's default would be a random port on every interface).
    * multicast scouting is off: a station's peers are named, never discovered by
      multicast (which also leaks between test runs and between stations on one LAN).
      Gossip scouting stays on in peer mode so peers that share a listener learn of each other.
    * `lease_ms`: the transport lease this process declares to its neighbours; they
      close the link (and drop its liveliness tokens) when it is silent that long.
    * `tls`: mutual TLS and access control; every endpoint must then be a `tls/` one. A client leaves
      the access control to its router (CLIENT_ACCESS_CONTROL).
      Gossip only passes on locators over links that are already authenticated.
    """
    if mode not in words(NetworkMode):
        raise ValueError(f"zenoh mode must be 'peer' or 'client', not {mode!r}")
    mode = NetworkMode(mode)
    if lease_ms < 100:
        raise ValueError(f"lease_ms={lease_ms} is too short to survive a scheduling hiccup (>= 100 ms)")
    listen, connect = list(listen), list(connect)
    if mode == NetworkMode.CLIENT and listen:
        raise ValueError("a zenoh client cannot listen: remove `listen` or use mode 'peer'")
    if tls is not None and any(not e.startswith("tls/") for e in (*listen, *connect)):
        raise ValueError(f"with TLS every endpoint must be tls/: {', '.join(e for e in (*listen, *connect))}")
    config = zenoh.Config()
    settings: dict[str, Any] = {
        "mode": mode.value,
        "connect/endpoints": connect,
        "scouting/multicast/enabled": False,
        "scouting/gossip/enabled": gossip and mode == NetworkMode.PEER,
        "transport/link/tx/lease": lease_ms,
        "transport/link/tx/keep_alive": KEEP_ALIVES_PER_LEASE,
        "transport/link/rx/max_message_size": max_message_bytes,
        # Keep retrying a connect endpoint in the background (a hub may boot before the
        # controller); a client's open() still fails without a router, which ZenohBus retries.
        "connect/exit_on_failure": False,
        "connect/retry": {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2},
    }
    if mode == NetworkMode.PEER:
        settings["listen/endpoints"] = listen
    if tls is not None:
        settings.update(tls.settings())
        if mode == NetworkMode.CLIENT:
            settings["access_control"] = CLIENT_ACCESS_CONTROL
    # Leave connect/timeout_ms alone: a peer's open() then returns after ~0.5 s even when
    # nobody listens yet, and keeps retrying in the background (timeout 0 stops the retries).
    for key, value in settings.items():
        config.insert_json5(key, json.dumps(value))
    return config


def zenoh_config_for(network: NetworkSettings) -> ZenohConfig:
    return zenoh_config(network.mode, network.listen, network.connect, network.lease_ms,
                        max_message_bytes=network.max_message_bytes)


def loopback_endpoint(port: int) -> str:
    """The endpoint of a process listening on this machine's loopback (a station run on one machine)."""
    return f"tcp/127.0.0.1:{port}"


def loopback_peer(port: int, lease_ms: int = DEFAULT_LEASE_MS, *, listen: Iterable[str] = ()) -> ZenohConfig:
    """A peer that connects to the controller listening on 127.0.0.1:`port` (the runner, the sim world)."""
    return zenoh_config("peer", listen=listen, connect=[loopback_endpoint(port)], lease_ms=lease_ms)


def is_client(config: ZenohConfig) -> bool:
    return bool(json.loads(config.get_json("mode")) == NetworkMode.CLIENT)
