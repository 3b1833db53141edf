"""The line controller's TLS: its certificate (name LINE_CONTROLLER_NAME) from the site's directory. The
routers decide what it may send (deploy/router/security.py): the stations' order keys and statuses only."""

from __future__ import annotations

from pathlib import Path

from common.bus.zenoh_config import TlsSettings
from common.config.modes import SecurityMode
from common.config.security import Identity, SecurityError, tls_files
from common.line.config import LineConfig
from deploy.router.security import LINE_CONTROLLER_NAME, peer_access_control


def line_controller_tls(line: LineConfig, certs: Path | None = None) -> TlsSettings | None:
    if line.security.mode is not SecurityMode.TLS:
        return None
    directory = certs or line.security.certs
    if directory is None:
        raise SecurityError(f"{line.path}: [security] certs: no certificate directory for the line controller")
    files = tls_files(directory, Identity(LINE_CONTROLLER_NAME, "operator"))
    return TlsSettings(files.root_ca, files.certificate, files.private_key, peer_access_control(line.routers),
                       verify_names=False)
