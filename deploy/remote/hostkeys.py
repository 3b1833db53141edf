"""Host key pinning: a deploy talks only to the machine whose key the station recorded.

The station keeps its own known_hosts file (`known_hosts` next to hubs.toml, or `--known-hosts FILE`),
not the user's: whoever deploys, from whichever machine, trusts the same keys, and the file can be
reviewed and versioned with the station. Every ssh of a deploy runs with `StrictHostKeyChecking=yes`
against it. On first contact there is nothing to check against: the key is recorded only when the
deploy says `--trust-new-host` (ssh-keyscan, its fingerprint printed), otherwise the deploy stops
before connecting. A key that differs from the recorded one is refused by ssh; the error says how to
replace it when the machine was really reinstalled.
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

from .ssh import SSH_EXIT_CONNECT, RemoteError, SshTarget

KNOWN_HOSTS = "known_hosts"
DEFAULT_SSH_PORT = 22


class HostKeyError(RemoteError):
    """The target's host key is not recorded (and may not be), or cannot be read."""

    def __init__(self, where: str, message: str) -> None:
        super().__init__(where, "host key check", SSH_EXIT_CONNECT, message)
        self.args = (message,)

    def __str__(self) -> str:
        return str(self.args[0])


def station_known_hosts(config_path: str | Path) -> Path:
    return Path(config_path).resolve().parent / KNOWN_HOSTS


def host_pattern(target: SshTarget) -> str:
    """How known_hosts names the target: `host`, or `[host]:port` on another port than 22."""
    if target.port and target.port != DEFAULT_SSH_PORT:
        return f"[{target.host}]:{target.port}"
    return target.host


def changed_key_hint(target: SshTarget) -> str:
    return (f"the host key of {target.where} is not the one recorded in {target.known_hosts}: refused (a reinstalled "
            f"machine, or someone in between). If the machine was reinstalled, check its new key's fingerprint on "
            f"it, remove the old one with `ssh-keygen -R '{host_pattern(target)}' -f {target.known_hosts}` and "
            f"deploy with --trust-new-host")


async def _run(*argv: str, stdin: bytes | None = None) -> tuple[int, str, str]:
    process = await asyncio.create_subprocess_exec(
        *argv, stdin=asyncio.subprocess.PIPE if stdin is not None else asyncio.subprocess.DEVNULL,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await process.communicate(stdin)
    assert process.returncode is not None
    return process.returncode, out.decode(errors="replace"), err.decode(errors="replace")


async def _why_unreachable(target: SshTarget) -> str:
    """ssh-keyscan says nothing of a refused or timed out connection: what a plain connect says."""
    try:
        connection = await asyncio.to_thread(socket.create_connection, (target.host, target.port or DEFAULT_SSH_PORT),
                                             10)
    except OSError as exc:
        return exc.strerror or str(exc)
    connection.close()
    return "it accepts connections but sent no SSH host key"


async def pin_host_key(target: SshTarget, trust_new: bool) -> str:
    """Make sure the target's key is recorded in its known_hosts file (recording it only if `trust_new`);
    what was done, for the progress line. Raises HostKeyError."""
    assert target.known_hosts is not None
    path, pattern = Path(target.known_hosts), host_pattern(target)
    if path.exists():
        code, _, _ = await _run("ssh-keygen", "-F", pattern, "-f", str(path))
        if code == 0:
            return f"host key pinned in {path}"
    if not trust_new:
        raise HostKeyError(target.where, (
            f"no host key of {pattern} is recorded in {path}: on first contact, check the machine's key fingerprint "
            f"(on it: `ssh-keygen -lf /etc/ssh/ssh_host_ed25519_key.pub`) and deploy with --trust-new-host"))
    port = ["-p", str(target.port)] if target.port else []
    code, out, err = await _run("ssh-keyscan", "-T", "10", *port, target.host)
    keys = [line for line in out.splitlines() if line.strip() and not line.startswith("#")]
    if not keys:
        raise HostKeyError(target.where, f"ssh to {target.where} failed: ssh-keyscan got no host key from {pattern} "
                                         f"({err.strip() or await _why_unreachable(target)})")
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as handle:
        handle.write("\n".join(keys) + "\n")
    _, fingerprints, _ = await _run("ssh-keygen", "-lf", "-", stdin=("\n".join(keys) + "\n").encode())
    shown = "; ".join(" ".join(line.split()[:2] + line.split()[-1:]) for line in fingerprints.splitlines())
    return f"new host: recorded its key in {path} ({shown})"
