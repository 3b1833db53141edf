"""`hubctl deploy` and `hubctl rollback` against a real OpenSSH server on loopback.

The test starts Debian's sshd on a free loopback port with its own host key, an
authorized key it generated and `StrictModes no`, running as the current user. The
deploys go into a temporary root (`--root`), and `systemctl`, `useradd`, `groupadd` and
`chown` on the "remote" PATH are shims that append their arguments to a log; a shim fails once
when a `fail-<command>-<argument>` file exists, which is how a failing remote step is
injected. No hub can start under a shim systemctl, so the deploys use `--no-wait`
(tests/test_hubwait.py covers the waiting); they use `--offline-deps` because the
target is this machine, whose python already has statehub's dependencies.
"""

from __future__ import annotations

import getpass
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.plumbing.lifecycle import free_port
from deploy.remote.wheel import Wheel, build_wheel
from tests.deploy_support import REPO, Run, hubctl, station_toml

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]  # a hung ssh must not hang the suite

SSHD = shutil.which("sshd") or next((p for p in ("/usr/sbin/sshd",) if os.access(p, os.X_OK)), None)
UNIT = "statehub-hub-pi-tool.service"
# The venv on the "target" is made by this interpreter (its base, when the tests run in a
# venv), whose site-packages already hold statehub's dependencies and pip (--offline-deps).
PYTHON = os.path.realpath(getattr(sys, "_base_executable", sys.executable))

SHIM = """#!/bin/sh
# A recording stand-in for {name}, installed by tests/test_deploy.py.
echo "{name} $*" >> {log}
if [ "{name}" = systemctl ] && [ "$1" = --version ]; then echo "systemd 252 (252.0-shim)"; exit 0; fi
for arg in "$@"; do
  if [ -f {dir}/fail-{name}-"$arg" ]; then
    rm -f {dir}/fail-{name}-"$arg"
    for unit in "$@"; do :; done
    echo "Job for $unit failed because the control process exited with error code (injected by the test)" >&2
    exit 1
  fi
done
exit 0
"""


@dataclass(frozen=True)
class SshServer:
    port: int
    key: Path
    known_hosts: Path
    shims: Path
    calls: Path  # what the shims recorded, one call a line

    def calls_since(self, mark: int) -> list[str]:
        return self.calls.read_text().splitlines()[mark:] if self.calls.exists() else []

    def mark(self) -> int:
        return len(self.calls_since(0))

    def fail_once(self, command: str, argument: str) -> None:
        (self.shims / f"fail-{command}-{argument}").touch()


@pytest.fixture(scope="module")
def sshd(tmp_path_factory):
    if SSHD is None:
        pytest.fail("tests/test_deploy.py deploys to a real SSH server and needs OpenSSH's sshd, which this "
                    "machine lacks: apt-get install -y openssh-server (Debian), then run the tests again")
    home = tmp_path_factory.mktemp("sshd")
    for key in ("host_key", "client_key"):
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "statehub-test", "-f", str(home / key)],
                       check=True, capture_output=True)
    (home / "authorized_keys").write_text((home / "client_key.pub").read_text())
    shims, calls = home / "shims", home / "calls.log"
    shims.mkdir()
    for name in ("systemctl", "useradd", "groupadd", "chown"):
        (shims / name).write_text(SHIM.format(name=name, log=calls, dir=shims))
        (shims / name).chmod(0o755)
    port = free_port()
    user = getpass.getuser()
    # SHLVL=1: bash sources ~/.bashrc for an ssh command only at shell level 1, and a
    # developer's .bashrc (pyenv init...) would cost a second per remote command.
    (home / "sshd_config").write_text(f"""Port {port}
ListenAddress 127.0.0.1
HostKey {home / "host_key"}
PidFile {home / "sshd.pid"}
AuthorizedKeysFile {home / "authorized_keys"}
StrictModes no
UsePAM no
PubkeyAuthentication yes
PasswordAuthentication no
KbdInteractiveAuthentication no
PermitRootLogin prohibit-password
AllowUsers {user}
SetEnv PATH={shims}:{os.environ.get("PATH", "/usr/bin:/bin")} SHLVL=1
LogLevel ERROR
""")
    if os.geteuid() == 0:
        # sshd started by root wants its privilege-separation directory (the ssh service makes it).
        Path("/run/sshd").mkdir(mode=0o755, exist_ok=True)
    log = (home / "sshd.log").open("w")
    process = subprocess.Popen([SSHD, "-D", "-e", "-f", str(home / "sshd_config")], stdout=log, stderr=log)
    try:
        deadline = time.monotonic() + 10
        while True:
            if process.poll() is not None:
                pytest.fail(f"sshd exited with {process.returncode}: {(home / 'sshd.log').read_text()}")
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            if time.monotonic() > deadline:
                pytest.fail(f"sshd did not listen on 127.0.0.1:{port} within 10 s")
            time.sleep(0.05)
        server = SshServer(port, home / "client_key", home / "known_hosts", shims, calls)
        # The shims must come first on the remote PATH, or the deploys would run the real systemctl.
        probe = subprocess.run(["ssh", *ssh_options(server), f"{user}@127.0.0.1", "command -v systemctl useradd"],
                               capture_output=True, text=True, timeout=30)
        assert probe.stdout.split() == [str(shims / "systemctl"), str(shims / "useradd")], (
            f"the remote PATH does not start with the shims: {probe.stdout!r} {probe.stderr!r}")
        server.calls.write_text("")
        yield server
    finally:
        process.terminate()
        process.wait(timeout=10)
        log.close()


def ssh_options(server: SshServer) -> list[str]:
    return ["-p", str(server.port), "-i", str(server.key), "-o", "BatchMode=yes", "-o", "IdentitiesOnly=yes",
            "-o", f"UserKnownHostsFile={server.known_hosts}", "-o", "StrictHostKeyChecking=accept-new"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Wheel:
    """Built once, the way `hubctl deploy` builds it."""
    return build_wheel(REPO, tmp_path_factory.mktemp("wheel"))


@dataclass
class Site:
    """A station file pointing hub pi-tool at the test's sshd, and a target root."""

    config: Path
    root: Path
    server: SshServer
    wheel: Wheel

    @property
    def base(self) -> Path:
        return self.root / "opt" / "statehub"

    @property
    def current(self) -> Path:
        return self.base / "hubs" / "pi-tool" / "current"

    def current_release(self) -> str | None:
        return os.path.basename(os.readlink(self.current)) if self.current.is_symlink() else None

    def log(self) -> list[dict[str, object]]:
        path = self.base / "releases.log"
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def args(self, *extra: str, wait: bool = False) -> list[str]:
        return ["--config", str(self.config), "--root", str(self.root), "--ssh-port", str(self.server.port),
                "--identity", str(self.server.key), "--no-sudo", *([] if wait else ["--no-wait"]), *extra]

    @property
    def known_hosts(self) -> Path:
        """The station's: next to its hubs.toml."""
        return self.config.parent / "known_hosts"

    def deploy(self, *extra: str, wheel: Path | None = None, wait: bool = False, trust: bool = True) -> Run:
        return hubctl("deploy", "pi-tool", *self.args("--offline-deps", "--python", PYTHON, "--wheel",
                                                      str(wheel or self.wheel.path),
                                                      *(["--trust-new-host"] if trust else []), *extra, wait=wait))

    def rollback(self, *extra: str) -> Run:
        return hubctl("rollback", "pi-tool", *self.args(*extra))

    def change_station(self, comment: str) -> None:
        """A different hubs.toml: a new release of the same wheel."""
        self.config.write_text(station_toml(hosts={"pi-tool": ("127.0.0.1", getpass.getuser())}, comment=comment))


@pytest.fixture
def site(tmp_path, sshd, wheel) -> Site:
    site = Site(tmp_path / "hubs.toml", tmp_path / "target", sshd, wheel)
    site.change_station("first")
    return site


def ok(run: Run) -> Run:
    assert run.code == 0, f"exit {run.code}\n--- out\n{run.out}\n--- err\n{run.err}"
    return run


def test_first_deploy_then_an_idempotent_redeploy(site):
    mark = site.server.mark()
    run = ok(site.deploy())
    for number in range(1, 11):
        assert f"[{number}/10] " in run.out
    assert "[10/10] wait for hub pi-tool on zenoh (liveliness, self-test) ... ok" in run.out
    assert "skipped (--no-wait)" in run.out

    release = site.current_release()
    assert release is not None and release.startswith(f"{site.wheel.version}-")
    rel = site.base / "releases" / release
    assert os.readlink(site.current) == str(rel)
    assert (rel / ".complete").exists() and (rel / site.wheel.name).exists()
    assert os.access(rel / "venv" / "bin" / "hubctl", os.X_OK)
    assert (rel / "hubs.toml").read_bytes() == site.config.read_bytes()
    assert (rel / "hubs.toml").stat().st_mode & 0o777 == 0o600  # device passwords: the service user's only
    assert f"new host: recorded its key in {site.known_hosts}" in run.out
    assert site.known_hosts.read_text().startswith(f"[127.0.0.1]:{site.server.port} ssh-ed25519 ")
    unit = (site.root / "etc" / "systemd" / "system" / UNIT).read_text()
    assert f"ExecStart={site.current}/venv/bin/python -P -m hubs pi-tool --config {site.current}/hubs.toml\n" in unit
    assert (rel / "units" / UNIT).read_text() == unit
    assert json.loads((rel / "release.json").read_text())["wheel_sha256"] == site.wheel.sha256

    calls = site.server.calls_since(mark)
    assert calls[-3:] == ["systemctl daemon-reload", f"systemctl enable --quiet {UNIT}", f"systemctl restart {UNIT}"]
    assert f"chown statehub:statehub {rel}/hubs.toml" in calls
    if subprocess.run(["id", "-u", "statehub"], capture_output=True).returncode != 0:
        assert any(c.startswith("useradd --system --user-group") and c.endswith(" statehub") for c in calls)
    [entry] = site.log()
    assert entry["action"] == "deploy" and entry["release"] == release and entry["previous"] is None
    stage = re.search(r"MB to (\S+)", run.out)
    assert stage is not None and not Path(stage.group(1)).exists(), "the staging directory was left behind"

    # The installed unit, its venv now real, loads in systemd without a complaint.
    unit_path = site.root / "etc" / "systemd" / "system" / UNIT
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        from tests.test_units import structural_problems

        assert structural_problems(unit_path.read_text(), 252) == []
    else:
        verify = subprocess.run([analyze, "verify", "--man=no", "--generators=no", str(unit_path)],
                                capture_output=True, text=True, timeout=60)
        assert (verify.returncode, verify.stdout + verify.stderr) == (0, "")

    # Deploying the same wheel and hubs.toml again reuses the release and only restarts; the key is pinned now.
    mark = site.server.mark()
    run = ok(site.deploy(trust=False))
    assert f"host key pinned in {site.known_hosts}" in run.out
    assert f"release {release} already there" in run.out
    assert "(the release is there: unit only)" in run.out
    assert f"reused {rel}" in run.out
    assert f"already {release}" in run.out
    assert site.current_release() == release
    assert [p.name for p in (site.base / "releases").iterdir() if not p.name.startswith(".")] == [release]
    assert len(site.log()) == 1  # nothing was switched
    assert site.server.calls_since(mark)[-1] == f"systemctl restart {UNIT}"

    # With waiting: the shim systemctl starts no hub, so none shows up on Zenoh.
    run = site.deploy("--wait-timeout", "1", "--zenoh-listen", "tcp/127.0.0.1:0",
                      "--zenoh-connect", f"tcp/127.0.0.1:{free_port()}", wait=True)
    assert run.code == 1
    assert "failed at step [10/10] wait for hub pi-tool on zenoh" in run.err
    assert "hub pi-tool did not come up on zenoh within 1 s: no liveliness token" in run.err
    assert f"current is {release} and its unit was restarted" in run.err


def test_a_new_host_needs_trust_and_a_changed_host_key_is_refused(site, tmp_path):
    mark = site.server.mark()
    run = site.deploy(trust=False)
    assert run.code == 1
    assert f"no host key of [127.0.0.1]:{site.server.port} is recorded in {site.known_hosts}" in run.err
    assert "--trust-new-host" in run.err
    assert not site.known_hosts.exists() and site.server.calls_since(mark) == [] and site.current_release() is None

    # Another key recorded for the address: ssh refuses the real one, with or without --trust-new-host.
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(tmp_path / "other")], check=True)
    site.known_hosts.write_text(f"[127.0.0.1]:{site.server.port} {(tmp_path / 'other.pub').read_text()}")
    for trust in (False, True):
        run = site.deploy(trust=trust)
        assert run.code == 1
        assert f"is not the one recorded in {site.known_hosts}: refused" in run.err, run.err
        assert f"ssh-keygen -R '[127.0.0.1]:{site.server.port}'" in run.err
    assert site.server.calls_since(mark) == [] and site.current_release() is None
    assert site.known_hosts.read_text().count("ssh-ed25519") == 1


def test_failed_deploys_leave_the_previous_release_running(site, tmp_path):
    ok(site.deploy())
    old = site.current_release()
    where = f"{getpass.getuser()}@127.0.0.1:{site.server.port}"

    # A wheel pip refuses: the deploy stops at the install, before anything runs it.
    broken = tmp_path / "statehub-0.0.1-py3-none-any.whl"
    with zipfile.ZipFile(broken, "w") as archive:
        archive.writestr("statehub/__init__.py", "")  # no .dist-info
    mark = site.server.mark()
    run = site.deploy(wheel=broken)
    assert run.code == 1
    assert "[6/10] install wheel on 127.0.0.1 (deps from the target's python) ... FAILED" in run.out
    assert "failed at step [6/10] install wheel on 127.0.0.1" in run.err
    assert f"install wheel failed on {where} (exit 1)" in run.err
    assert ".dist-info directory not found" in run.err  # pip's own words
    assert f"current is unchanged ({old}): the running hub was not touched" in run.err
    assert site.current_release() == old
    assert site.server.calls_since(mark) == ["systemctl --version"]  # the probe's; nothing was (re)started
    assert len(site.log()) == 1

    # A new release whose restart fails: current, the unit and the process go back to the old one.
    site.change_station("second")
    site.server.fail_once("systemctl", "restart")
    mark = site.server.mark()
    run = site.deploy()
    assert run.code == 1
    assert "[9/10] restart statehub-hub-pi-tool.service on 127.0.0.1 ... FAILED" in run.out
    assert f"deploy of hub pi-tool failed at step [9/10] restart {UNIT} on 127.0.0.1 ({where})" in run.err
    assert f"systemctl restart {UNIT} failed on {where} (exit 1)" in run.err
    assert "Job for statehub-hub-pi-tool.service failed because the control process exited" in run.err
    assert f"reverted: current -> {old} again and restarted" in run.err
    assert site.current_release() == old
    assert [c for c in site.server.calls_since(mark) if "restart" in c] == [f"systemctl restart {UNIT}"] * 2
    actions = [(e["action"], e["release"]) for e in site.log()]
    new = actions[1][1]
    assert actions == [("deploy", old), ("deploy", new), ("revert", old)] and new != old
    unit = (site.root / "etc/systemd/system" / UNIT).read_text()
    assert unit == (site.base / "releases" / str(old) / "units" / UNIT).read_text()


def test_rollback_walks_back_through_the_deploys(site):
    ok(site.deploy())
    first = site.current_release()
    site.change_station("second")
    ok(site.deploy())
    second = site.current_release()
    assert second != first

    mark = site.server.mark()
    run = ok(site.rollback())
    assert f"current {second}, rolling back to {first}" in run.out
    assert site.current_release() == first
    assert site.server.calls_since(mark) == ["systemctl daemon-reload", f"systemctl restart {UNIT}"]
    assert site.log()[-1]["action"] == "rollback" and site.log()[-1]["previous"] == second

    run = site.rollback()  # `first` was the first deploy: nothing before it
    assert run.code == 1
    assert f"has no release of hub pi-tool before {first}" in run.err and "pick one with --to" in run.err
    assert site.current_release() == first

    ok(site.rollback("--to", second))
    assert site.current_release() == second


def test_dry_run_changes_nothing(site):
    mark = site.server.mark()
    run = ok(hubctl("deploy", "pi-tool", *site.args("--dry-run", "--offline-deps")))
    assert "[2/10] build wheel (dry run)" in run.out and "pip wheel --no-deps" in run.out
    assert "[9/10] restart statehub-hub-pi-tool.service on 127.0.0.1 (dry run)" in run.out
    assert "  | systemctl restart statehub-hub-pi-tool.service" in run.out
    assert "  | mv -T " in run.out
    assert not site.root.exists()
    assert site.server.calls_since(mark) == []


def test_unreachable_host_fails_at_the_probe(site):
    port = free_port()  # nobody listens there
    run = hubctl("deploy", "pi-tool", *site.args("--offline-deps", "--wheel", str(site.wheel.path),
                                                 "--ssh-port", str(port), "--trust-new-host"))
    assert run.code == 1
    assert f"failed at step [3/10] probe {getpass.getuser()}@127.0.0.1:{port}" in run.err
    assert "ssh to" in run.err and "Connection refused" in run.err
    assert "current is unchanged (none): the running hub was not touched" in run.err
    assert not site.root.exists()


def test_unknown_hub_fails_at_the_check(site):
    run = hubctl("deploy", "pi-nope", *site.args("--offline-deps"))
    assert run.code == 1
    assert f"failed at step [1/10] check {site.config}" in run.err and "no hub named 'pi-nope'" in run.err
    assert "nothing on the target was changed" in run.err
