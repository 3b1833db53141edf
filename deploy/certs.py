"""`hubctl certs init|issue`: the station's certificate authority and its holders' certificates.

`init` makes the station CA (`ca.crt`, `ca.key`); `issue NAME` (a hub, the controller's
name, an operator of [security] operators) or `issue HOST` (every hub and the controller
on that host) makes `NAME.crt` + `NAME.key`, signed by the CA. The common name is the
holder's name, the organizational unit its role (hub, controller, operator), the subject
alternative names the hosts it can be reached at (hubs.toml's `host`, listen/connect
addresses, localhost). Keys are ECDSA P-256, written 0600 in a 0700 directory outside the
repository: a directory inside a git work tree is refused unless `--force`.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from common.config.hubs_toml import StationConfig, load_config
from common.config.security import ROLES, Identity, Role, SecurityError, cert_dir, roles_of

CA_DAYS = 3650
LEAF_DAYS = 825
LOOPBACK_HOSTS = ("localhost", "127.0.0.1")


@dataclass(frozen=True)
class Issued:
    identity: Identity
    certificate: Path
    private_key: Path
    hosts: tuple[str, ...]


def inside_git_work_tree(path: Path) -> Path | None:
    """The work tree `path` would be written into, if any (a `.git` in it or a parent)."""
    for parent in (path.resolve(), *path.resolve().parents):
        if (parent / ".git").exists():
            return parent
    return None


def prepare_dir(directory: Path, *, force: bool = False) -> Path:
    tree = inside_git_work_tree(directory)
    if tree is not None and not force:
        raise SecurityError(f"{directory} is inside the git work tree {tree}: private keys must not be kept in a "
                            f"repository (give another --dir, or --force)")
    directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(directory, 0o700)
    return directory


def _write_private(path: Path, data: bytes) -> None:
    path.unlink(missing_ok=True)  # a new file, so that its mode is 0600 from the start
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _name(common_name: str, unit: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name),
                      x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, unit)])


def init_ca(directory: Path, station: str, *, force: bool = False, days: int = CA_DAYS) -> Path:
    """Make the station CA in `directory` (refused if one is there, unless `force`)."""
    prepare_dir(directory, force=force)
    if (directory / "ca.crt").exists() and not force:
        raise SecurityError(f"{directory / 'ca.crt'} exists: a new CA invalidates every certificate it issued "
                            f"(--force to replace it)")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = _name(f"{station} station CA", "ca")
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write_private(directory / "ca.key", _key_pem(key))
    _write_private(directory / "ca.crt", cert.public_bytes(serialization.Encoding.PEM))
    return directory / "ca.crt"


def _alt_name(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def issue(directory: Path, identity: Identity, hosts: Iterable[str], *, force: bool = False,
          days: int = LEAF_DAYS) -> Issued:
    """Sign a certificate for `identity`, valid for `hosts`, with the CA in `directory`."""
    prepare_dir(directory, force=force)
    try:
        ca_key = serialization.load_pem_private_key((directory / "ca.key").read_bytes(), password=None)
        ca_cert = x509.load_pem_x509_certificate((directory / "ca.crt").read_bytes())
    except FileNotFoundError as exc:
        raise SecurityError(f"no station CA in {directory} ({exc.filename}): run `hubctl certs init` first") from None
    if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
        raise SecurityError(f"{directory / 'ca.key'}: not an EC private key made by `hubctl certs init`")
    names = tuple(dict.fromkeys(h for h in (*hosts, *LOOPBACK_HOSTS) if h))
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(_name(identity.name, identity.role)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName([_alt_name(h) for h in names]), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    issued = Issued(identity, directory / f"{identity.name}.crt", directory / f"{identity.name}.key", names)
    _write_private(issued.private_key, _key_pem(key))
    _write_private(issued.certificate, cert.public_bytes(serialization.Encoding.PEM))
    return issued


def role_in_certificate(path: Path) -> tuple[str, str]:
    """(common name, role) of a certificate: what the access control and `hubctl certs` read."""
    cert = x509.load_pem_x509_certificate(path.read_bytes())
    cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    ou = cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)
    return (str(cn[0].value) if cn else "", str(ou[0].value) if ou else "")


def _endpoint_host(endpoint: str) -> str:
    address = endpoint.partition("/")[2].rsplit(":", 1)[0].strip("[]")
    return "" if address in ("0.0.0.0", "::", "") else address


def hosts_of(config: StationConfig, identity: Identity) -> list[str]:
    """Where `identity` is reached: its host in hubs.toml and its listeners; for the controller also
    the addresses the others connect to (they connect to it)."""
    if identity.role in ("operator", "viewer"):
        return []
    process = "controller" if identity.role == "controller" else identity.name
    section = config.controller if identity.role == "controller" else config.hubs[identity.name]
    network = config.network_for(process)
    endpoints = [*network.listen, *(config.network.connect if identity.role == "controller" else [])]
    return [section.host, *(_endpoint_host(e) for e in endpoints)]


def identities_for(config: StationConfig, target: str, role: Role | None) -> list[Identity]:
    """The holders `target` names: a host (every hub and the controller on it; `role` picks among them), else
    a hub, the controller's name or an operator, whose role in hubs.toml must be `role` if given (the
    access control trusts the name, so the certificate's role must agree with it)."""
    on_host = [Identity(h.name, "hub") for h in config.hubs.values() if h.host == target]
    if config.controller.host == target:
        on_host.insert(0, Identity(config.controller.name, "controller"))
    if on_host:
        chosen = [i for i in on_host if role is None or i.role == role]
        if not chosen:
            raise SecurityError(f"{config.path}: no {role} runs on host {target!r}")
        return chosen
    roles = roles_of(config)
    if target not in roles:
        raise SecurityError(f"{config.path}: {target!r} is no host, hub, controller or operator "
                            f"(security.operators) of hubs.toml")
    if role is not None and role != roles[target]:
        raise SecurityError(f"{config.path}: {target!r} has role {roles[target]} in hubs.toml, not {role}")
    return [Identity(target, roles[target])]


def issue_for_station(directory: Path, config: StationConfig, identities: Iterable[Identity], *,
                      extra_hosts: Iterable[str] = (), force: bool = False) -> list[Issued]:
    return [issue(directory, i, [*hosts_of(config, i), *extra_hosts], force=force) for i in identities]


def cmd_certs(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    directory = cert_dir(config, args.dir)
    if args.certs_command == "init":
        path = init_ca(directory, config.station.name, force=args.force)
        print(f"station CA of {config.station.name}: {path} (its key {directory / 'ca.key'}, mode 0600)")
        return 0
    identities = identities_for(config, args.target, args.role)
    for issued in issue_for_station(directory, config, identities, extra_hosts=args.host, force=args.force):
        print(f"{issued.identity.role} {issued.identity.name}: {issued.certificate} + {issued.private_key.name} "
              f"(0600), valid for {', '.join(issued.hosts)}")
    return 0


def register_certs_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `certs init` and `certs issue` to hubctl."""
    certs = sub.add_parser("certs", help="the station's certificates for [security] mode = \"tls\"")
    certs_sub = certs.add_subparsers(dest="certs_command", required=True)
    init = certs_sub.add_parser("init", help="make the station's certificate authority")
    issue_cmd = certs_sub.add_parser("issue", help="issue the certificate of a hub, the controller, an operator, "
                                                   "or of every process on a host")
    issue_cmd.add_argument("target", metavar="HOST|NAME")
    issue_cmd.add_argument("--role", choices=ROLES, help="check that hubs.toml gives NAME this role")
    issue_cmd.add_argument("--host", action="append", default=[], help="another host name or address it is "
                                                                       "reached at (repeatable)")
    for parser in (init, issue_cmd):
        parser.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
        parser.add_argument("--dir", help="the certificate directory (default: [security] certs, else "
                                          "~/.config/statehub/STATION/certs)")
        parser.add_argument("--force", action="store_true",
                            help="replace existing files; allow a directory inside a git work tree")
        parser.set_defaults(func=cmd_certs)
