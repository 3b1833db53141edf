"""systemd units of the station's processes, rendered from hubs.toml.

One unit per hub (`statehub-hub-<hub>.service`) and one for the controller
(`statehub-controller.service`). They run the release that `current` points at
(deploy/remote/layout.py), so switching a version is a symlink switch and a restart; the unit
text itself only changes when the hub's devices or this template change.

Choices, each for a reason:

* `ExecStart=python -P -m hubs HUB` (and `-m controller`): the release's own interpreter, `-P`
  so that the working directory (the controller's is its writable state directory) never
  shadows the installed packages.
* `ExecStartPre=python -P -m hubs HUB --selftest`: systemd refuses to start a hub whose
  devices fail the self-test (DESIGN.md §6); the report lands in the journal.
* `Restart=always` and no start limit (`StartLimitIntervalSec=0`): a hub is stateless
  and must come back by itself once its device or the network returns, however long
  that takes; a unit that gave up would need a person at the ECU. The backoff keeps a
  crash loop cheap: from systemd 254 on, `RestartSteps`/`RestartMaxDelaySec` grow the
  delay from 1 s to 60 s; older systemd (Debian/Raspberry Pi OS bookworm ship 252) has
  no growing delay, so a fixed 5 s. The policy itself is deploy/remote/restart_policy.py, which
  `hubctl up` follows too.
* `User=statehub`: its own unprivileged user. A hub reaches its devices through Unix
  groups only: `i2c` for an MCP23017 on /dev/i2c-* (nutrunner), `dialout` for a serial
  RFID reader, each only when such a device runs in `real` mode. CAN needs no group and
  no capability: raw CAN sockets are open to every user, and bringing can0 up (bitrate)
  belongs to the OS (systemd-networkd), not to the hub. So no AmbientCapabilities at
  all, and an empty capability bounding set.
* Hardening: read-only system and no home (`ProtectSystem=strict`, `ProtectHome`), no
  privilege gain, no kernel tunables, modules, logs, clock or hostname, no namespaces,
  a native-syscall `@system-service` filter. Left out on purpose: `PrivateDevices` (it
  would hide /dev/i2c-* and /dev/ttyUSB*), `MemoryDenyWriteExecute` (libffi closures,
  used through ctypes/cffi by device libraries, need writable+executable pages), and
  `DevicePolicy=closed` (it would tie the unit to kernel driver names; the groups
  already scope device access).
* `Type=notify` with `WatchdogSec=`: the process says READY=1 once it serves (a hub in its safe
  state, the controller with its mirrors taken) and WATCHDOG=1 from its loop (common/plumbing/sdnotify.py),
  so systemd restarts a loop that hangs, not only a process that exits. `MemoryMax=` and
  `TasksMax=` bound what a runaway (a flood of payloads, a leak, a thread per request) can take
  from the ECU; the controller's bounds are wider for its planner process.
* Output goes to the journal under the unit's name (`journalctl -u statehub-hub-pi-tool`);
  `PYTHONUNBUFFERED` so that lines appear when written.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from common.config.hubs_toml import HubConfig, StationConfig
from common.config.modes import DeviceMode, SecurityMode
from common.line.config import LineConfig

from .layout import CONTROLLER_UNIT, Layout, hub_unit_name
from .restart_policy import unit_restart_policy

# Device types whose real driver opens a device node, and the group owning such nodes
# on Raspberry Pi OS and Debian.
DEVICE_GROUPS = {"nutrunner": "i2c", "rfid": "dialout"}
SERVICE_USER = "statehub"
# The layout of a real target (no --root prefix).
ON_TARGET = Layout()
# The oldest systemd with RestartSteps= and RestartMaxDelaySec= (a growing restart delay).
BACKOFF_SYSTEMD = 254
# What Debian bookworm and Raspberry Pi OS bookworm ship: the default when unknown.
DEFAULT_SYSTEMD = 252


@dataclass(frozen=True)
class Limits:
    """How long a silent loop is tolerated, and what the process may take."""

    watchdog: str
    memory: str
    tasks: int

    def lines(self) -> list[str]:
        return [f"WatchdogSec={self.watchdog}", f"MemoryMax={self.memory}", f"TasksMax={self.tasks}"]


HUB_LIMITS = Limits(watchdog="10s", memory="256M", tasks=64)
CONTROLLER_LIMITS = Limits(watchdog="30s", memory="2G", tasks=256)


@dataclass(frozen=True)
class Unit:
    name: str  # e.g. statehub-hub-pi-tool.service
    text: str


def hub_groups(hub: HubConfig) -> list[str]:
    """The supplementary groups the hub's devices need (only devices in `real` mode touch /dev)."""
    return sorted({DEVICE_GROUPS[d.type] for d in hub.devices.values()
                   if d.mode == DeviceMode.REAL and d.type in DEVICE_GROUPS})




_HARDENING = [
    "NoNewPrivileges=yes",
    "CapabilityBoundingSet=",
    "ProtectSystem=strict",
    "ProtectHome=yes",
    "PrivateTmp=yes",
    "ProtectKernelTunables=yes",
    "ProtectKernelModules=yes",
    "ProtectKernelLogs=yes",
    "ProtectControlGroups=yes",
    "ProtectClock=yes",
    "ProtectHostname=yes",
    "ProtectProc=invisible",
    "RestrictNamespaces=yes",
    "RestrictRealtime=yes",
    "RestrictSUIDSGID=yes",
    "LockPersonality=yes",
    "RemoveIPC=yes",
    "UMask=0077",
    "SystemCallArchitectures=native",
    "SystemCallFilter=@system-service",
    "SystemCallErrorNumber=EPERM",
]


def _render(description: str, service: Iterable[str], limits: Limits, systemd_version: int) -> str:
    lines = [
        "# Rendered by `hubctl units` / `hubctl deploy` from hubs.toml: edit hubs.toml, not this file.",
        "[Unit]",
        f"Description={description}",
        "After=network-online.target",
        "Wants=network-online.target",
        *unit_restart_policy(systemd_version, BACKOFF_SYSTEMD).unit_lines(),
        "",
        "[Service]",
        "Type=notify",
        *service,
        *limits.lines(),
        *unit_restart_policy(systemd_version, BACKOFF_SYSTEMD).service_lines(),
        "TimeoutStopSec=10s",
        "StandardOutput=journal",
        "StandardError=journal",
        "Environment=PYTHONUNBUFFERED=1",
        *_HARDENING,
        "",
        "[Install]",
        "WantedBy=multi-user.target",
        "",
    ]
    return "\n".join(lines)


def _quote(arg: str) -> str:
    """An argument of an Exec line (systemd splits on whitespace and expands % and $)."""
    arg = arg.replace("%", "%%").replace("$", "$$")
    if re.search(r"[\s\"'\\;]", arg):
        return '"' + arg.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return arg


def _exec(*args: str) -> str:
    return " ".join(_quote(a) for a in args)


def _certs_option(config: StationConfig, layout: Layout, hub: str | None) -> list[str]:
    return ["--certs", layout.certs(hub)] if config.security.mode == SecurityMode.TLS else []


def hub_unit(config: StationConfig, hub: str, layout: Layout = ON_TARGET,
             systemd_version: int = DEFAULT_SYSTEMD) -> Unit:
    settings = config.hubs.get(hub)
    if settings is None:
        raise KeyError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    current = layout.current(hub)
    hub_process, toml = [f"{current}/venv/bin/python", "-P", "-m", "hubs", hub], f"{current}/hubs.toml"
    name = hub_unit_name(hub)
    devices = ", ".join(f"{r} ({d.type}, {d.mode})" for r, d in settings.devices.items()) or "no devices"
    groups = hub_groups(settings)
    service = [
        f"User={SERVICE_USER}",
        f"Group={SERVICE_USER}",
        *([f"SupplementaryGroups={' '.join(groups)}"] if groups else []),
        f"ExecStartPre={_exec(*hub_process, '--config', toml, '--selftest')}",
        f"ExecStart={_exec(*hub_process, '--config', toml, *_certs_option(config, layout, hub))}",
        f"SyslogIdentifier={name.removesuffix('.service')}",
        # The hub's device nodes: PrivateDevices would hide them (see the module docstring).
        "PrivateDevices=no",
        # zenoh enumerates interfaces over netlink; python-can's socketcan uses AF_CAN.
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK AF_CAN",
    ]
    return Unit(name, _render(f"statehub hub {hub} of station {config.station.name}: {devices}",
                              service, HUB_LIMITS, systemd_version))


def controller_unit(config: StationConfig, layout: Layout = ON_TARGET,
                    systemd_version: int = DEFAULT_SYSTEMD) -> Unit:
    current = layout.current(None)
    python, toml = f"{current}/venv/bin/python", f"{current}/hubs.toml"
    # The controller persists its state (DESIGN.md §7) in [controller] db, relative to its
    # working directory: /var/lib/statehub, which systemd creates for the service user.
    state_dirs = ["statehub"]
    db_parent = str(Path(config.controller.db).parent)
    extra: list[str] = []
    if Path(config.controller.db).is_absolute():
        extra.append(f"ReadWritePaths={db_parent}")
    elif db_parent not in ("", "."):
        state_dirs.append(f"statehub/{db_parent}")
    service = [
        f"User={SERVICE_USER}",
        f"Group={SERVICE_USER}",
        f"StateDirectory={' '.join(state_dirs)}",
        "WorkingDirectory=%S/statehub",
        *extra,
        f"ExecStart={_exec(python, '-P', '-m', 'controller', '--config', toml, *_certs_option(config, layout, None))}",
        "SyslogIdentifier=statehub-controller",
        "PrivateDevices=yes",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK",
    ]
    return Unit(CONTROLLER_UNIT, _render(f"statehub controller {config.controller.name} of station "
                                         f"{config.station.name}", service, CONTROLLER_LIMITS, systemd_version))


ROUTER_LIMITS = Limits(watchdog="10s", memory="512M", tasks=64)


def router_unit_name(router: str) -> str:
    return f"statehub-router-{router}.service"


def router_unit(line_toml: str, router: str, *, secured: bool, base: str = "/opt/statehub/router",
                systemd_version: int = DEFAULT_SYSTEMD) -> Unit:
    """A Zenoh router of the line (deploy/router/): the same template as the hubs' and the controller's, with
    no state and no devices; its release under `base`/current like theirs."""
    current = f"{base}/current"
    certs = ["--certs", f"{base}/certs"] if secured else []
    name = router_unit_name(router)
    command = _exec(f"{current}/venv/bin/python", "-P", "-m", "deploy.router", "--config", line_toml,
                    "--name", router, *certs)
    service = [
        f"User={SERVICE_USER}",
        f"Group={SERVICE_USER}",
        f"ExecStart={command}",
        f"SyslogIdentifier={name.removesuffix('.service')}",
        "PrivateDevices=yes",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK",
    ]
    return Unit(name, _render(f"statehub Zenoh router {router} of the line", service, ROUTER_LIMITS,
                              systemd_version))


# One round asks every station in turn, each up to the line controller's ASK_TIMEOUT_S when it does not
# answer: a line with many stations unreachable at once has long rounds, and a round is one watchdog ping.
LINE_CONTROLLER_LIMITS = Limits(watchdog="60s", memory="512M", tasks=64)
LINE_CONTROLLER_UNIT = "statehub-line-controller.service"
STATE_ROOT = Path("/var/lib")


def line_controller_unit(line: LineConfig, line_toml: str, *, base: str = "/opt/statehub/line",
                         systemd_version: int = DEFAULT_SYSTEMD) -> Unit:
    """The line controller (deploy/line/controller.py), the routers' template; its release under `base`/current.

    `line` is the line.toml as loaded here, `line_toml` where it lies on the target: `[line] db`, relative to
    it, is where the controller keeps every handover. Under /var/lib systemd creates that directory for the
    service user (`StateDirectory=`); elsewhere (the default `var/line.sqlite` beside line.toml) the unit may
    write there (`ReadWritePaths=`), and the directory must exist and be the service user's."""
    current = f"{base}/current"
    db = line.db if line.db.is_absolute() and not line.db.is_relative_to(line.path.parent) else \
        Path(line_toml).parent / line.db.relative_to(line.path.parent)
    if db.is_relative_to(STATE_ROOT):
        storage = f"StateDirectory={db.parent.relative_to(STATE_ROOT)}"
    else:
        storage = f"ReadWritePaths={db.parent}"
    secured = line.security.mode is SecurityMode.TLS
    certs = ["--certs", f"{base}/certs"] if secured else []
    command = _exec(f"{current}/venv/bin/python", "-P", "-m", "deploy.line.controller", "--config", line_toml,
                    *certs)
    service = [
        f"User={SERVICE_USER}",
        f"Group={SERVICE_USER}",
        storage,
        f"ExecStart={command}",
        f"SyslogIdentifier={LINE_CONTROLLER_UNIT.removesuffix('.service')}",
        "PrivateDevices=yes",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK",
    ]
    return Unit(LINE_CONTROLLER_UNIT, _render(f"statehub line controller of line {line.name}", service,
                                              LINE_CONTROLLER_LIMITS, systemd_version))


def station_units(config: StationConfig, layout: Layout = ON_TARGET,
                  systemd_version: int = DEFAULT_SYSTEMD) -> list[Unit]:
    """The controller's unit, then each hub's, in hubs.toml order."""
    return [controller_unit(config, layout, systemd_version),
            *(hub_unit(config, hub, layout, systemd_version) for hub in config.hubs)]


def write_units(units: Iterable[Unit], out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for unit in units:
        path = out / unit.name
        path.write_text(unit.text, encoding="utf-8")
        written.append(path)
    return written


def parse_systemd_version(text: str) -> int | None:
    """`systemd 252 (252.38-1~deb12u1)` (first line of `systemctl --version`) -> 252."""
    match = re.match(r"\s*systemd\s+(\d+)", text)
    return int(match.group(1)) if match else None


def local_systemd_version() -> int | None:
    """The systemd version of this machine, or None when it has no systemd tools."""
    for tool in ("systemd-analyze", "systemctl"):
        path = shutil.which(tool)
        if path is None:
            continue
        try:
            out = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=10).stdout
        except (OSError, subprocess.SubprocessError):
            continue
        version = parse_systemd_version(out)
        if version is not None:
            return version
    return None
