"""Certificates for a station run on this machine (`hubctl up`) when hubs.toml says [security] mode = "tls".

A run gets a throw-away CA and one certificate per process (the controller, every hub,
the first operator of [security] operators for hubctl's own watchers) in a private
temporary directory, removed when the run ends; the processes get it as `--certs DIR`.
An insecure station runs on plain TCP and says so in the banner.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from common.bus.station_net import station_zenoh_config
from common.bus.zenoh_config import ZenohConfig, loopback_peer
from common.config.hubs_toml import StationConfig
from common.config.modes import SecurityMode
from common.config.security import identity_of, operator_identity
from common.model import Model
from common.plumbing.lifecycle import network
from deploy.certs import init_ca, issue_for_station


@contextlib.contextmanager
def local_certs(config: StationConfig) -> Iterator[Path | None]:
    """A certificate directory for every process of a loopback run (None when the station is insecure)."""
    if config.security.mode != SecurityMode.TLS:
        yield None
        return
    directory = Path(tempfile.mkdtemp(prefix=f"statehub-{config.station.name}-certs-"))
    try:
        init_ca(directory, config.station.name, force=True)
        processes = ["controller", *config.hubs, operator_identity(config).name]
        issue_for_station(directory, config, [identity_of(config, p) for p in processes])
        yield directory
    finally:
        shutil.rmtree(directory, ignore_errors=True)


def watcher_zenoh_config(config: StationConfig, model: Model, port: int, certs: Path | None) -> ZenohConfig:
    """hubctl's own session on a loopback run (status watcher, sim world): an operator connecting to the
    controller on 127.0.0.1:`port`."""
    if certs is None:
        return loopback_peer(port, config.network.lease_ms)
    base = network(config, "controller", port)
    return station_zenoh_config(config, model, operator_identity(config), base, certs=certs, listen=[],
                                connect=base.listen)
