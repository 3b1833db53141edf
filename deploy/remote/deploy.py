"""`hubctl deploy HUB`: install a hub on its ECU over SSH and (re)start its systemd unit.

Ten steps, each printed with its outcome and duration:

     1 check hubs.toml        (local) the station file and model, the hub's host and user
     2 build the wheel        (local) reproducible: its hash names the release
     3 probe the target       uid, python, systemd, the current release, whether this one is there
     4 upload                 wheel, hubs.toml and the rendered unit, one tar stream
     5 create the venv        /opt/statehub/releases/<version>-<hash>/venv (reused when complete)
     6 install the wheel      and the release's hubs.toml; `.complete` last
     7 install the unit       service user, device groups, unit file, daemon-reload, enable
     8 switch `current`       atomically (ln -s to a temp name, mv -T), logged in releases.log
     9 restart the unit       ExecStartPre runs the self-test: a broken hub does not start
    10 wait for the hub       its liveliness token and self-test report over Zenoh

Until step 8 the running version is untouched: a failure leaves `current` where it
was (and step 7 puts the previous unit back). When the restart fails, `current`, the
unit and the process go back to the previous release at once. A release is named by
the hash of the wheel and of hubs.toml, so deploying the same code and station file
again reuses the release and only restarts the unit.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import getpass
import hashlib
import shlex
import socket
import tempfile
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from common.bus.zenoh_bus import ZenohBus
from common.config.hubs_toml import StationConfig, load_station
from common.config.modes import SecurityMode
from common.config.security import cert_dir, identity_of, tls_files
from common.stations import is_file_reference
from common.wire.selftest_report import format_report

from . import scripts
from .hostkeys import station_known_hosts
from .hubwait import DEFAULT_LISTEN, HubWaitError, HubWatch, watch_config
from .layout import Layout, hub_unit_name
from .progress import Progress, StepFailed
from .ssh import Remote, RemoteError, SshTarget, pack_files
from .units import DEFAULT_SYSTEMD, hub_groups, hub_unit, parse_systemd_version
from .wheel import SOURCE_DATE_EPOCH, Wheel, build_command, build_wheel, default_source, inspect_wheel

DEPLOY_STEPS = 10
PLACEHOLDER_RELEASE = "<version>-<hash>"


class DeployFailed(RuntimeError):
    """A deploy or rollback stopped: the failed step, where, why, and what state the target is left in."""


@dataclass(frozen=True)
class Connection:
    """How to reach the target and where things go on it."""

    ssh_port: int | None = None
    identity: str | None = None
    ssh_options: tuple[str, ...] = ()
    root: str = "/"
    sudo: bool = True
    dry_run: bool = False
    known_hosts: str | None = None  # default: the station's, next to hubs.toml (deploy/remote/hostkeys.py)
    trust_new_host: bool = False


@dataclass(frozen=True)
class Waiting:
    wait: bool = True
    timeout: float = 30.0
    listen: str = DEFAULT_LISTEN
    connect: tuple[str, ...] = ()


@dataclass(frozen=True)
class DeployOptions:
    config: Path
    hub: str
    connection: Connection = Connection()
    waiting: Waiting = Waiting()
    offline_deps: bool = False
    wheel: Path | None = None
    source: Path | None = None
    python: str = "python3"


def now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def who() -> str:
    return f"{getpass.getuser()}@{socket.gethostname()}"


def release_id(wheel: Wheel, hubs_toml: bytes) -> str:
    digest = hashlib.sha256(bytes.fromhex(wheel.sha256) + hashlib.sha256(hubs_toml).digest()).hexdigest()
    return f"{wheel.version}-{digest[:12]}"


def target_of(config: StationConfig, hub: str, connection: Connection) -> SshTarget:
    settings = config.hubs[hub]
    known_hosts = connection.known_hosts or str(station_known_hosts(config.path))
    return SshTarget(settings.host, settings.ssh_user, connection.ssh_port, connection.identity,
                     connection.ssh_options, known_hosts)


class UnknownHub(LookupError):
    pass


class StationFileError(OSError):
    pass


def read_station_file(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise StationFileError(f"cannot read {path}: {exc.strerror or exc}") from None


def hub_cert_files(config: StationConfig, hub: str) -> list[tuple[str, Path]]:
    """The CA certificate and the hub's certificate and key to ship ([security] mode "tls"), from this
    machine's certificate directory (`hubctl certs issue HUB`)."""
    if config.security.mode != SecurityMode.TLS:
        return []
    files = tls_files(cert_dir(config), identity_of(config, hub))
    return [(p.name, p) for p in (files.root_ca, files.certificate, files.private_key)]


def check_hub(config: StationConfig, hub: str) -> None:
    if hub not in config.hubs:
        raise UnknownHub(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    if is_file_reference(config.station.model):
        # The release is the wheel and hubs.toml: a model file beside hubs.toml would not reach the Pi.
        raise StationFileError(f"{config.path}: station.model is the file {config.station.model.rpartition(':')[0]}: "
                               f"a deployed hub imports its model from an installed package; make the station a "
                               f"package (`hubctl new-station`, docs/new-station.md) and name its module:function")


def check_probe(probe: scripts.Probe, where: str, python: str, *, needs_ensurepip: bool, sudo: bool) -> None:
    """The target can run statehub: a recent python that can make venvs, and systemd; and the
    SSH user may do what the privileged steps do."""
    if sudo and probe.uid != 0 and not probe.sudo:
        user = where.split("@")[0]
        raise RemoteError(where, "probe", 1, f"{user} cannot sudo without a password there: allow it "
                                             f"(`{user} ALL=(ALL) NOPASSWD: ALL` in /etc/sudoers.d/), deploy as "
                                             f"root, or give --no-sudo when {user} owns the paths (--root)")
    if probe.python is None:
        raise RemoteError(where, "probe", 1, f"{python!r} not found on the target (install python3)")
    if probe.python < scripts.MIN_PYTHON:
        found = ".".join(map(str, probe.python))
        raise RemoteError(where, "probe", 1, f"{python} is {found}; statehub needs Python "
                                             f"{'.'.join(map(str, scripts.MIN_PYTHON))} or newer")
    if needs_ensurepip and not probe.ensurepip:
        raise RemoteError(where, "probe", 1, f"{python} -m venv cannot install pip (no ensurepip): "
                                             f"apt-get install python3-venv")
    if parse_systemd_version(probe.systemd) is None:
        raise RemoteError(where, "probe", 1, "no systemctl on the target: statehub runs as systemd units")


async def revert(remote: Remote, layout: Layout, hub: str, unit: str, previous: str | None, failed_release: str,
                 *, switched: bool) -> str:
    """Best effort: undo a deploy that failed after touching the unit or `current`; says what it did."""
    log = scripts.log_line(hub=hub, action="revert", release=previous, previous=failed_release, by=who(), time=now())
    script = scripts.revert(layout, hub, unit, previous, switched=switched, log=log)
    try:
        await remote.run(script, what="revert", privileged=True)
    except RemoteError as exc:
        return f"REVERT FAILED, the target needs a look: {exc}"
    if previous is None:
        return "reverted: the unit is disabled and removed again (there was no previous release)"
    if switched:
        return f"reverted: current -> {previous} again and restarted (the previous version is running)"
    return f"reverted: the unit of {previous} is back; current unchanged ({previous} keeps running)"


@contextlib.asynccontextmanager
async def hub_watch(config: StationConfig, hub: str, waiting: Waiting) -> AsyncIterator[HubWatch | None]:
    """A HubWatch on the station's network, opened before the restart; None without waiting."""
    if not waiting.wait:
        yield None
        return
    zconfig = watch_config(config, hub, listen=waiting.listen, connect=list(waiting.connect) or None)
    async with ZenohBus(zconfig) as bus, HubWatch(bus, config.station.name, hub) as watch:
        yield watch


async def restart_step(progress: Progress, remote: Remote, layout: Layout, hub: str, release: str,
                       previous: str | None, watch: HubWatch | None) -> None:
    unit, host = hub_unit_name(hub), remote.target.host
    async with progress.step(f"restart {unit} on {host}") as note:
        if watch is not None:
            watch.restarted()
        try:
            await remote.run(scripts.restart(unit), what=f"systemctl restart {unit}", privileged=True)
        except RemoteError as exc:
            if previous == release:  # a redeploy of the running release: nothing else to go back to
                raise
            outcome = await revert(remote, layout, hub, unit, previous, release, switched=True)
            raise RemoteError(exc.where, exc.what, exc.returncode, f"{exc.stderr}\n{outcome}") from exc
        note.detail = f"running {release}"


async def wait_step(progress: Progress, watch: HubWatch | None, hub: str, waiting: Waiting) -> None:
    async with progress.step(f"wait for hub {hub} on zenoh (liveliness, self-test)") as note:
        if watch is None:
            note.detail = "" if progress.dry_run else "skipped (--no-wait)"
            return
        report = await watch.wait(waiting.timeout)
        if not report.ok:
            raise HubWaitError(f"hub {hub} is alive but its self-test FAILED:\n{format_report(report)}")
        note.detail = f"alive, self-test PASS ({len(report.devices)} devices)"


def state_after(step: int, previous: str | None, release: str) -> str:
    """What a failure at `step` leaves running (the revert outcome of steps 7 and 9 is in the error)."""
    if step <= 2:
        return "nothing on the target was changed"
    if step <= 8:
        return f"current is unchanged ({previous or 'none'}): the running hub was not touched"
    if step == 9:
        # After a revert the error says what it did; a redeploy of the running release has nothing to go back to.
        return f"current is {release}, whose unit failed to start" if previous == release else ""
    return f"current is {release} and its unit was restarted"


async def deploy(opts: DeployOptions, out: TextIO | None = None) -> None:
    """Raises DeployFailed with the step, the host, the remote error and the state left behind."""
    conn = opts.connection
    progress = Progress(DEPLOY_STEPS, out=out, dry_run=conn.dry_run)
    layout = Layout(conn.root)
    hub = opts.hub
    where, previous, release = "this machine", None, PLACEHOLDER_RELEASE
    try:
        async with progress.step(f"check {opts.config}", always=True) as note:
            hubs_toml = read_station_file(opts.config)
            config, _model = await asyncio.to_thread(load_station, opts.config)
            check_hub(config, hub)
            settings = config.hubs[hub]
            devices = ", ".join(f"{r} ({d.type}, {d.mode})" for r, d in settings.devices.items())
            certs = hub_cert_files(config, hub)  # checked here, before anything is uploaded
            links = f"mTLS, certificate {certs[1][1]}" if certs else "INSECURE plain TCP links ([security] mode)"
            note.detail = f"hub {hub} on {settings.ssh_user}@{settings.host}: {devices}; {links}"
        target = target_of(config, hub, conn)

        with tempfile.TemporaryDirectory(prefix="hubctl-wheel-") as tmp:
            wheel: Wheel | None = None
            async with progress.step("check wheel" if opts.wheel else "build wheel", always=bool(opts.wheel)) as note:
                source = opts.source or default_source()
                if opts.wheel:
                    wheel = inspect_wheel(opts.wheel)
                elif conn.dry_run:
                    command = shlex.join(build_command(Path(f"<copy of {source}>"), Path(tmp)))
                    progress.show_command(f"$ SOURCE_DATE_EPOCH={SOURCE_DATE_EPOCH} {command}")
                else:
                    wheel = await asyncio.to_thread(build_wheel, source, Path(tmp))
                if wheel is not None:
                    note.detail = f"{wheel.name}, sha256 {wheel.sha256[:12]}"
            if wheel is not None:
                release = release_id(wheel, hubs_toml)

            async with Remote(target, dry_run=conn.dry_run, sudo=conn.sudo, show=progress.show_command,
                              trust_new_host=conn.trust_new_host) as remote:
                where = target.where
                probe = await probe_step(progress, remote, layout, hub, release, opts)
                previous = probe.current
                await install_steps(progress, remote, config, layout, opts, probe, wheel, release, hubs_toml)
    except StepFailed as exc:
        raise DeployFailed(failure_text("deploy", hub, exc, where, state_after(exc.number, previous, release))) \
            from exc


async def probe_step(progress: Progress, remote: Remote, layout: Layout, hub: str | None, release: str,
                     opts: DeployOptions) -> scripts.Probe:
    where = remote.target.where
    async with progress.step(f"probe {where}") as note:
        result = await remote.run(scripts.probe(layout, hub, release, opts.python), what="probe")
        if progress.dry_run:
            return scripts.Probe(uid=-1, python=None, ensurepip=True, pip=True, systemd="", current=None,
                                 release="none")
        probe = scripts.parse_probe(result.stdout)
        remote.remote_uid = probe.uid
        check_probe(probe, where, opts.python, needs_ensurepip=not (opts.offline_deps and probe.pip),
                    sudo=remote.sudo)
        sudo = " (sudo)" if probe.uid != 0 and remote.sudo else ""
        note.detail = (f"{remote.pinned}; uid {probe.uid}{sudo}, python {'.'.join(map(str, probe.python or ()))}, "
                       f"{probe.systemd.split(' (')[0]}, current {probe.current or 'none'}, release {release} "
                       f"{'already there' if probe.release == 'complete' else 'new'}")
        return probe


async def install_steps(progress: Progress, remote: Remote, config: StationConfig, layout: Layout,
                        opts: DeployOptions, probe: scripts.Probe, wheel: Wheel | None, release: str,
                        hubs_toml: bytes) -> None:
    """Steps 4 to 10."""
    hub, unit, host, dry = opts.hub, hub_unit_name(opts.hub), remote.target.host, progress.dry_run
    previous = probe.current
    unit_text = hub_unit(config, hub, layout, parse_systemd_version(probe.systemd) or DEFAULT_SYSTEMD).text
    wheel_name = wheel.name if wheel else "statehub-<version>-py3-none-any.whl"
    have_release = probe.release == "complete"
    stage = "<stage>"
    staged = False  # a staging directory exists on the target, to remove if a step fails
    try:
        async with progress.step(f"upload to {host}") as note:
            files: list[tuple[str, Path | bytes]] = [(unit, unit_text.encode()), *hub_cert_files(config, hub)]
            if not have_release:
                files += [(wheel_name, wheel.path if wheel else b""), ("hubs.toml", hubs_toml)]
            payload = b"" if dry else pack_files(files)
            result = await remote.run(scripts.upload(), what="upload", stdin=payload,
                                      stdin_note=f"tar of {', '.join(n for n, _ in files)}")
            if not dry:
                stage, staged = result.stdout.strip().splitlines()[-1], True
            note.detail = f"{len(payload) / 1e6:.2f} MB to {stage}" + (" (the release is there: unit only)"
                                                                       if have_release else "")

        async with progress.step(f"create venv on {host}") as note:
            script = scripts.create_venv(layout, release, opts.python, system_site_packages=opts.offline_deps,
                                         without_pip=opts.offline_deps and probe.pip)
            note.detail = (await remote.run(script, what="create venv", privileged=True)).stdout.strip()

        deps = "deps from the target's python" if opts.offline_deps else "deps from PyPI"
        async with progress.step(f"install wheel on {host} ({deps})") as note:
            metadata = {"release": release, "wheel": wheel_name, "wheel_sha256": wheel.sha256 if wheel else "",
                        "hubs_toml_sha256": hashlib.sha256(hubs_toml).hexdigest(), "by": who(), "time": now()}
            script = scripts.install(layout, release, stage, wheel_name, offline_deps=opts.offline_deps,
                                     metadata=metadata)
            note.detail = (await remote.run(script, what="install wheel", privileged=True)).stdout.strip()

        async with progress.step(f"install {unit} on {host}") as note:
            groups = hub_groups(config.hubs[hub])
            try:
                certs = (layout.certs(hub), [n for n, _ in hub_cert_files(config, hub)]) \
                    if config.security.mode == SecurityMode.TLS else None
                await remote.run(scripts.install_unit(layout, release, stage, unit, groups, certs=certs),
                                 what=f"install {unit}", privileged=True)
            except RemoteError as exc:
                outcome = await revert(remote, layout, hub, unit, previous, release, switched=False)
                raise RemoteError(exc.where, exc.what, exc.returncode, f"{exc.stderr}\n{outcome}") from exc
            staged = False  # the script removed it
            note.detail = f"user statehub, groups {' '.join(groups) or '-'}, enabled"

        async with contextlib.AsyncExitStack() as stack:
            async with progress.step(f"switch current on {host}") as note:
                # The watch opens first: should it fail (a busy --zenoh-listen port), nothing has switched.
                watch = await stack.enter_async_context(hub_watch(config, hub, Waiting(wait=False) if dry
                                                                  else opts.waiting))
                if previous == release:
                    note.detail = f"already {release}"
                else:
                    log = scripts.log_line(hub=hub, action="deploy", release=release, previous=previous, by=who(),
                                           time=now())
                    await remote.run(scripts.switch(layout, hub, release, log), what="switch current",
                                     privileged=True)
                    note.detail = f"{previous or 'none'} -> {release}"
            await restart_step(progress, remote, layout, hub, release, previous, watch)
            await wait_step(progress, watch, hub, opts.waiting)
    finally:
        if staged:
            with contextlib.suppress(RemoteError):  # never hide the error that got us here
                await remote.run(scripts.cleanup(stage), what="clean up", check=False)


def failure_text(action: str, hub: str, exc: StepFailed, where: str, state: str) -> str:
    cause = str(exc.cause).strip().replace("\n", "\n    ")
    return (f"{action} of hub {hub} failed at step [{exc.number}/{exc.total}] {exc.title} ({where}):\n"
            f"    {cause}" + (f"\n{state}" if state else ""))
