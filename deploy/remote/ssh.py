"""Running shell scripts on a target over the system's OpenSSH client.

Plain `ssh` rather than a Python SSH library: it is on every machine that deploys, it
reads the user's ~/.ssh/config, agent and known hosts, and it needs no dependency.

* `BatchMode=yes`: never prompt (a deploy runs unattended; a missing key is an error);
* `StrictHostKeyChecking=yes` against the station's own known_hosts file: a key is recorded
  only on first contact with `--trust-new-host`, a changed key is refused (deploy/remote/hostkeys.py);
* one master connection per deploy (`ControlMaster`), so that the dozen steps do not each
  pay a key exchange on a Raspberry Pi; it is closed when the deploy ends;
* scripts run under `sh -c` (POSIX, whatever the login shell), privileged ones through
  `sudo -n` unless the SSH user is root; files travel as a tar stream on stdin (no sftp
  subsystem needed).
"""

from __future__ import annotations

import asyncio
import shlex
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

SSH_EXIT_CONNECT = 255  # ssh's own failure (connection, authentication), not the remote command's


@dataclass(frozen=True)
class SshTarget:
    host: str
    user: str
    port: int | None = None
    identity: str | None = None
    options: tuple[str, ...] = ()  # extra `-o` options
    known_hosts: str | None = None  # the station's known_hosts file: the only keys trusted

    @property
    def where(self) -> str:
        return f"{self.user}@{self.host}" + (f":{self.port}" if self.port else "")


@dataclass(frozen=True)
class Result:
    returncode: int
    stdout: str
    stderr: str


class RemoteError(RuntimeError):
    """A remote command failed: where, what, and what it said on stderr."""

    def __init__(self, where: str, what: str, returncode: int, stderr: str, changed_key_hint: str = "") -> None:
        self.where, self.what, self.returncode, self.stderr = where, what, returncode, stderr.strip()
        if returncode == SSH_EXIT_CONNECT and changed_key_hint and "Host key verification failed" in stderr:
            message = changed_key_hint
        elif returncode == SSH_EXIT_CONNECT:
            message = f"ssh to {where} failed: {self.stderr or 'no error message'}"
        else:
            message = f"{what} failed on {where} (exit {returncode})" + (f":\n{self.stderr}" if self.stderr else "")
        super().__init__(message)


@dataclass
class Remote:
    """Runs scripts on one target. With `dry_run`, shows each command through `show` instead."""

    target: SshTarget
    dry_run: bool = False
    sudo: bool = True  # use `sudo -n` for privileged scripts when the SSH user is not root
    trust_new_host: bool = False  # record the host key on first contact (deploy/remote/hostkeys.py)
    show: Callable[[str], None] = print
    _control_dir: tempfile.TemporaryDirectory[str] | None = field(default=None, init=False, repr=False)
    remote_uid: int | None = field(default=None, init=False)
    _shown_ssh: bool = field(default=False, init=False, repr=False)
    pinned: str = field(default="", init=False)  # what the host key check did, once done

    # --- ssh command lines ---------------------------------------------------------------------
    def ssh_args(self, command: str) -> list[str]:
        t = self.target
        args = ["ssh", "-o", "BatchMode=yes", "-o", "StrictHostKeyChecking=yes",
                "-o", "ConnectTimeout=10", "-o", "ServerAliveInterval=5", "-o", "ServerAliveCountMax=6"]
        if t.known_hosts:
            args += ["-o", f'UserKnownHostsFile="{t.known_hosts}"', "-o", "GlobalKnownHostsFile=/dev/null"]
        if self._control_dir is not None:
            args += ["-o", "ControlMaster=auto", "-o", f"ControlPath={self._control_dir.name}/%C",
                     "-o", "ControlPersist=60"]
        if t.port:
            args += ["-p", str(t.port)]
        if t.identity:
            args += ["-i", t.identity, "-o", "IdentitiesOnly=yes"]
        for option in t.options:
            args += ["-o", option]
        return [*args, f"{t.user}@{t.host}", "--", command]

    def _wrap(self, script: str, privileged: bool) -> str:
        command = f"sh -c {shlex.quote(script)}"
        if privileged and self.sudo and self.remote_uid != 0:
            command = f"sudo -n {command}"
        return command

    # --- lifecycle ------------------------------------------------------------------------------
    async def __aenter__(self) -> Remote:
        if not self.dry_run:
            # A short path: a unix socket path must stay under ~100 bytes.
            self._control_dir = tempfile.TemporaryDirectory(prefix="hubctl-ssh-", dir="/tmp")
        return self

    async def __aexit__(self, *_exc: object) -> None:
        if self._control_dir is None:
            return
        args = self.ssh_args("true")
        exit_args = [*args[:-3], "-O", "exit", *args[-3:-2]]  # `ssh [options] -O exit user@host`
        process = await asyncio.create_subprocess_exec(*exit_args, stdin=asyncio.subprocess.DEVNULL,
                                                       stdout=asyncio.subprocess.DEVNULL,
                                                       stderr=asyncio.subprocess.DEVNULL)
        await process.wait()
        self._control_dir.cleanup()
        self._control_dir = None

    # --- running --------------------------------------------------------------------------------
    async def run(self, script: str, *, what: str, privileged: bool = False, stdin: bytes | None = None,
                  check: bool = True, stdin_note: str = "") -> Result:
        """Run `script` with sh on the target. `what` names it in errors. Raises RemoteError
        when it exits non-zero and `check` (always when ssh itself failed)."""
        args = self.ssh_args(self._wrap(script, privileged))
        if self.dry_run:
            self._show_dry(script, privileged, stdin_note)
            return Result(0, "", "")
        if not self.pinned and self.target.known_hosts:
            from .hostkeys import pin_host_key

            self.pinned = await pin_host_key(self.target, self.trust_new_host)
        process = await asyncio.create_subprocess_exec(
            *args, stdin=asyncio.subprocess.PIPE if stdin is not None else asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        out, err = await process.communicate(stdin)
        assert process.returncode is not None
        result = Result(process.returncode, out.decode(errors="replace"), err.decode(errors="replace"))
        if result.returncode == SSH_EXIT_CONNECT or (check and result.returncode != 0):
            from .hostkeys import changed_key_hint

            raise RemoteError(self.target.where, what, result.returncode, result.stderr or result.stdout,
                              changed_key_hint(self.target) if self.target.known_hosts else "")
        return result

    def _show_dry(self, script: str, privileged: bool, stdin_note: str) -> None:
        """The ssh command line once, then each script as it would run (quoting it again would bury it)."""
        if not self._shown_ssh:
            self._shown_ssh = True
            self.show(f"(every remote script runs as: {shlex.join(self.ssh_args('SCRIPT')[:-1])} "
                      f"'[sudo -n] sh -c SCRIPT'; sudo when privileged and the user is not root)")
        how = "privileged" if privileged else "as the ssh user"
        self.show(f"on {self.target.where}, {how}" + (f", stdin: {stdin_note}" if stdin_note else "") + ":")
        for line in script.rstrip("\n").splitlines():
            self.show(f"  | {line}")


def pack_files(files: Sequence[tuple[str, Path | bytes]]) -> bytes:
    """A tar stream of (name, local file or content), to unpack with `tar -x` on the target."""
    import io
    import tarfile

    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name, source in files:
            data = source.read_bytes() if isinstance(source, Path) else source
            info = tarfile.TarInfo(name)
            info.size, info.mode = len(data), 0o644
            tar.addfile(info, io.BytesIO(data))
    return buffer.getvalue()
