"""The zenoh config of one process of a station: its network from hubs.toml, secured as [security] says.

Every process that joins a station's bus (a hub, the controller, a console, hubctl's
watchers) opens its session with `station_zenoh_config`: in `tls` mode the endpoints of
hubs.toml become `tls/` ones, the process presents its own certificate (its identity,
common/config/security.py) and enforces the station's access control (common/config/acl.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from common.bus.zenoh_config import TlsSettings, ZenohConfig, zenoh_config
from common.config.acl import access_control
from common.config.hubs_toml import NetworkConfig, StationConfig
from common.config.modes import SecurityMode
from common.config.security import INSECURE_BANNER, Identity, cert_dir, tls_endpoints, tls_files
from common.model import Model


def tls_settings(config: StationConfig, model: Model, identity: Identity,
                 certs: str | Path | None = None) -> TlsSettings | None:
    """`identity`'s TLS files and the station's access control; None in insecure mode."""
    if config.security.mode != SecurityMode.TLS:
        return None
    files = tls_files(cert_dir(config, certs), identity)
    return TlsSettings(files.root_ca, files.certificate, files.private_key, access_control(config, model),
                       verify_names=config.security.verify_names)


def station_zenoh_config(config: StationConfig, model: Model, identity: Identity, network: NetworkConfig, *,
                         certs: str | Path | None = None, listen: Sequence[str] | None = None,
                         connect: Sequence[str] | None = None) -> ZenohConfig:
    """The session config of `identity` on `network` (`listen`/`connect` replace the network's)."""
    listen = list(network.listen if listen is None else listen)
    connect = list(network.connect if connect is None else connect)
    tls = tls_settings(config, model, identity, certs)
    if tls is not None:
        where = f"{config.path}: {identity.role} {identity.name}"
        listen, connect = tls_endpoints(listen, where), tls_endpoints(connect, where)
    return zenoh_config(network.mode, listen, connect, network.lease_ms, tls=tls,
                        max_message_bytes=network.max_message_bytes)


def security_banner(config: StationConfig) -> str:
    """One line for a process's start: how its links are protected."""
    if config.security.mode == SecurityMode.TLS:
        return "links: mutual TLS with the station's certificates, access control on"
    return INSECURE_BANNER
