"""Certificates for a line run on this machine (`hubctl line up`) when line.toml says [security] mode = "tls".

One throw-away CA for the site and a certificate per holder: each router, the line controller, and every
holder of every station (its controller, hubs and operators, names unique on the line), in a private
temporary directory removed when the run ends; every process gets it as `--certs DIR`.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from common.config.hubs_toml import load_config
from common.config.modes import SecurityMode
from common.config.security import Identity, identity_of, roles_of
from common.line.config import LineConfig
from deploy.certs import init_ca, issue
from deploy.router.security import LINE_CONTROLLER_NAME, check_unique_names

LOOPBACK = ("127.0.0.1", "localhost")


def line_identities(line: LineConfig) -> list[Identity]:
    """Every certificate of the line. A router's and the line controller's role (the certificate's OU) is
    "controller" / "operator": the roles hubs.toml knows; the routers' access control reads names only."""
    configs = [load_config(station.config) for station in line.stations.values()]
    check_unique_names(configs, line.routers)
    identities = [Identity(router, "controller") for router in line.routers]
    identities.append(Identity(LINE_CONTROLLER_NAME, "operator"))
    for config in configs:
        identities += [identity_of(config, "controller" if role == "controller" else name)
                       for name, role in roles_of(config).items()]
    return identities


def issue_line(directory: Path, line: LineConfig) -> None:
    init_ca(directory, line.name, force=True)
    for identity in line_identities(line):
        issue(directory, identity, LOOPBACK, force=True)


@contextlib.contextmanager
def line_certs(line: LineConfig) -> Iterator[Path | None]:
    """A certificate directory for every process of the run (None on an insecure line)."""
    if line.security.mode is not SecurityMode.TLS:
        yield None
        return
    directory = Path(tempfile.mkdtemp(prefix=f"statehub-line-{line.name}-certs-"))
    try:
        issue_line(directory, line)
        yield directory
    finally:
        shutil.rmtree(directory, ignore_errors=True)
