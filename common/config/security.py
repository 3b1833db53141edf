"""Who a process is on the station's network, and the files that prove it ([security] of hubs.toml).

In `tls` mode every link is mutual TLS with certificates of the station's own CA
(`hubctl certs init|issue`, deploy/certs.py), and every process enforces the access
control that common/config/acl.py derives from hubs.toml: the certificate's common name is
its holder's name (a hub, the controller, an operator), its organizational unit the
holder's role. In `insecure` mode links are plain TCP and anyone who reaches a
listener may say anything: for a single-machine `hubctl up` only.

The certificate directory holds `ca.crt` (and the CA's `ca.key` where certificates are
issued), and `NAME.crt` + `NAME.key` per holder. It lives outside the repository:
[security] certs, else ~/.config/statehub/{station}/certs; a process's `--certs DIR`
overrides both (`hubctl up` issues a throw-away set for its run).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from common.config.hubs_toml import StationConfig

Role = Literal["hub", "controller", "operator", "viewer"]
ROLES: tuple[Role, ...] = ("hub", "controller", "operator", "viewer")  # viewer: the overview page, reads only
INSECURE_BANNER = ("INSECURE: [security] mode = \"insecure\": plain TCP links, no authentication, no access "
                   "control; anyone reaching a listener may command the station. For one machine only.")


class SecurityError(ValueError):
    """A certificate that is missing, or a name/role that hubs.toml does not give."""


@dataclass(frozen=True)
class Identity:
    """A process's name on the network (its certificate's CN) and role (the certificate's OU)."""

    name: str
    role: Role


@dataclass(frozen=True)
class TlsFiles:
    root_ca: Path
    certificate: Path
    private_key: Path


def roles_of(config: StationConfig) -> dict[str, Role]:
    """Every holder hubs.toml names and its role."""
    roles: dict[str, Role] = {hub: "hub" for hub in config.hubs}
    roles[config.controller.name] = "controller"
    roles.update({name: "operator" for name in config.security.operators})
    roles[config.overview.name] = "viewer"
    return roles


def identity_of(config: StationConfig, process: str) -> Identity:
    """The identity of "controller", of a hub, or of an operator named in [security] operators."""
    if process == "controller":
        return Identity(config.controller.name, "controller")
    role = roles_of(config).get(process)
    if role is None:
        raise SecurityError(f"{config.path}: {process!r} is neither a hub, the controller ({config.controller.name}) "
                            f"nor an operator of [security] operators ({', '.join(config.security.operators)})")
    return Identity(process, role)


def operator_identity(config: StationConfig, name: str | None = None) -> Identity:
    """An operator tool's identity: `name`, or the first of [security] operators."""
    operators = config.security.operators
    if name is None:
        if not operators:
            raise SecurityError(f"{config.path}: security.operators is empty: no operator certificate to use")
        name = operators[0]
    identity = identity_of(config, name)
    if identity.role != "operator":
        raise SecurityError(f"{config.path}: {name!r} is a {identity.role}, not an operator "
                            f"(security.operators: {', '.join(operators)})")
    return identity


def viewer_identity(config: StationConfig) -> Identity:
    """The overview page's identity ([overview] name): the viewer role, which may only read the station."""
    return Identity(config.overview.name, "viewer")


def cert_dir(config: StationConfig, override: str | Path | None = None) -> Path:
    """Where the station's certificates are: `override`, [security] certs (relative to hubs.toml), or
    ~/.config/statehub/{station}/certs."""
    if override:
        return Path(override).expanduser()
    if config.security.certs:
        path = Path(config.security.certs).expanduser()
        return path if path.is_absolute() else Path(config.path).parent / path
    return Path.home() / ".config" / "statehub" / config.station.name / "certs"


def tls_files(directory: Path, identity: Identity) -> TlsFiles:
    """The CA certificate, and `identity`'s certificate and key, which must exist."""
    files = TlsFiles(directory / "ca.crt", directory / f"{identity.name}.crt", directory / f"{identity.name}.key")
    for path in (files.root_ca, files.certificate, files.private_key):
        if not path.is_file():
            how = ("hubctl certs init" if path == files.root_ca
                   else f"hubctl certs issue {identity.name} --role {identity.role}")
            raise SecurityError(f"no {path} for the {identity.role} {identity.name} ([security] mode = \"tls\"): "
                                f"run `{how}`, or give the directory with --certs")
    return files


def tls_endpoints(endpoints: Iterable[str], where: str) -> list[str]:
    """hubs.toml's `tcp/` endpoints as `tls/` ones (the file says where, [security] says how)."""
    result = []
    for endpoint in endpoints:
        protocol, sep, address = endpoint.partition("/")
        if not sep or protocol not in ("tcp", "tls"):
            raise SecurityError(f"{where}: endpoint {endpoint!r}: with [security] mode = \"tls\" only tcp/ or tls/ "
                                f"endpoints can be used (they become tls/)")
        result.append(f"tls/{address}")
    return result
