"""systemd units rendered from hubs.toml, `hubctl units` and `hubctl config check`.

Every rendered unit must load in systemd without a single complaint. With
`systemd-analyze` on the machine (Debian's `systemd` package) that is what is checked:
`systemd-analyze verify` exits 0 *and prints nothing* (it exits 0 even for an unknown
key, which it only warns about). Without it the units get a strict structural check
instead: known sections and keys only, the required keys, absolute executable commands.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from common.config.hubs_toml import parse_config
from deploy.remote.layout import Layout
from deploy.remote.units import (
    BACKOFF_SYSTEMD,
    DEFAULT_SYSTEMD,
    controller_unit,
    hub_unit,
    local_systemd_version,
    parse_systemd_version,
    station_units,
    write_units,
)
from tests.deploy_support import hubctl, station_toml

SYSTEMD_ANALYZE = shutil.which("systemd-analyze")

# Keys systemd 252 knows, in the sections the units use (the fallback check's vocabulary).
KNOWN_KEYS = {
    "Unit": {"Description", "After", "Wants", "Requires", "StartLimitIntervalSec", "StartLimitBurst", "Documentation"},
    "Service": {
        "Type", "User", "Group", "SupplementaryGroups", "ExecStartPre", "ExecStart", "SyslogIdentifier",
        "PrivateDevices", "RestrictAddressFamilies", "Restart", "RestartSec", "TimeoutStopSec", "StandardOutput",
        "StandardError", "Environment", "NoNewPrivileges", "CapabilityBoundingSet", "ProtectSystem", "ProtectHome",
        "PrivateTmp", "ProtectKernelTunables", "ProtectKernelModules", "ProtectKernelLogs", "ProtectControlGroups",
        "ProtectClock", "ProtectHostname", "ProtectProc", "RestrictNamespaces", "RestrictRealtime",
        "RestrictSUIDSGID", "LockPersonality", "RemoveIPC", "UMask", "SystemCallArchitectures", "SystemCallFilter",
        "SystemCallErrorNumber", "StateDirectory", "WorkingDirectory", "ReadWritePaths", "WatchdogSec", "MemoryMax",
        "TasksMax",
    },
    "Install": {"WantedBy"},
}
NEWER_KEYS = {"RestartSteps": 254, "RestartMaxDelaySec": 254}
REQUIRED = {"Unit": {"Description", "After", "Wants"}, "Service": {"Type", "User", "ExecStart", "Restart"},
            "Install": {"WantedBy"}}
BOOLEANS = {"NoNewPrivileges", "ProtectHome", "PrivateTmp", "ProtectKernelTunables", "ProtectKernelModules",
            "ProtectKernelLogs", "ProtectControlGroups", "ProtectClock", "ProtectHostname", "RestrictNamespaces",
            "RestrictRealtime", "RestrictSUIDSGID", "LockPersonality", "RemoveIPC", "PrivateDevices"}


def structural_problems(text: str, systemd_version: int) -> list[str]:
    """What systemd would complain about, as far as a parser that is not systemd can tell."""
    problems: list[str] = []
    section: str | None = None
    seen: dict[str, set[str]] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        header = re.fullmatch(r"\[(\w+)\]", line)
        if header:
            section = header.group(1)
            if section not in KNOWN_KEYS:
                problems.append(f"{number}: unknown section [{section}]")
            seen.setdefault(section, set())
            continue
        if section is None or "=" not in line:
            problems.append(f"{number}: not a key=value line inside a section: {line!r}")
            continue
        key, value = line.split("=", 1)
        seen[section].add(key)
        known = KNOWN_KEYS.get(section, set())
        if key in NEWER_KEYS and section == "Service":
            if systemd_version < NEWER_KEYS[key]:
                problems.append(f"{number}: {key} needs systemd {NEWER_KEYS[key]}, the target has {systemd_version}")
        elif key not in known:
            problems.append(f"{number}: unknown key {key} in [{section}]")
        if key in BOOLEANS and value not in ("yes", "no"):
            problems.append(f"{number}: {key}={value} is not a boolean")
        if key in ("ExecStart", "ExecStartPre"):
            binary = Path(value.split()[0].lstrip("-+!@:"))
            if not binary.is_absolute():
                problems.append(f"{number}: {key} runs a relative path {binary}")
            elif not (binary.is_file() and binary.stat().st_mode & 0o111):
                problems.append(f"{number}: {key}: {binary} is not executable")
    for name, keys in REQUIRED.items():
        missing = keys - seen.get(name, set())
        if missing:
            problems.append(f"[{name}] lacks {', '.join(sorted(missing))}")
    return problems


def unit_problems(path: Path, systemd_version: int) -> list[str]:
    if SYSTEMD_ANALYZE:
        result = subprocess.run([SYSTEMD_ANALYZE, "verify", "--man=no", "--generators=no", str(path)],
                                capture_output=True, text=True, timeout=60)
        output = (result.stdout + result.stderr).strip()
        return [f"systemd-analyze verify exit {result.returncode}: {output}"] if result.returncode or output else []
    return structural_problems(path.read_text(), systemd_version)


def fake_install(root: Path, layout: Layout, processes: list[str | None]) -> None:
    """`systemd-analyze verify` wants the ExecStart binaries to exist: a venv whose python is a stub."""
    for process in processes:
        python_path = Path(layout.current(process)) / "venv" / "bin" / "python"
        python_path.parent.mkdir(parents=True, exist_ok=True)
        python_path.write_text("#!/bin/sh\nexit 0\n")
        python_path.chmod(0o755)


@pytest.fixture
def station():
    # One hub with hardware in real mode, so that the device groups are rendered too.
    return parse_config(station_toml(modes={"nr": "real", "rfid": "real"}), "hubs.toml")


def test_every_rendered_unit_loads_cleanly(tmp_path, station, record_property):
    version = local_systemd_version() if SYSTEMD_ANALYZE else DEFAULT_SYSTEMD
    assert version is not None
    layout = Layout(str(tmp_path / "root"))
    fake_install(tmp_path, layout, [None, *station.hubs])
    paths = write_units(station_units(station, layout, version), tmp_path / "units")
    record_property("unit_check", "systemd-analyze verify" if SYSTEMD_ANALYZE else "structural")
    assert len(paths) == len(station.hubs) + 1
    problems = {p.name: unit_problems(p, version) for p in paths}
    assert {name: found for name, found in problems.items() if found} == {}


def test_structural_check_catches_what_systemd_would_reject(tmp_path):
    stub = tmp_path / "hubctl"
    stub.write_text("#!/bin/sh\n")
    stub.chmod(0o755)
    good = f"[Unit]\nDescription=x\nAfter=a\nWants=a\n[Service]\nType=exec\nUser=u\nExecStart={stub} hub\n" \
           f"Restart=always\n[Install]\nWantedBy=multi-user.target\n"
    assert structural_problems(good, 252) == []
    assert structural_problems(good.replace("Restart=always", "Restart=always\nRestartSteps=5"), 252) == [
        "10: RestartSteps needs systemd 254, the target has 252"]
    assert structural_problems(good.replace("Type=exec", "Tpye=exec"), 252)[0] == "6: unknown key Tpye in [Service]"
    assert "not executable" in structural_problems(good.replace(str(stub), str(tmp_path / "nope")), 252)[0]


def test_hub_unit_runs_the_current_release_with_self_test_and_backoff(station):
    layout = Layout("/")
    text = hub_unit(station, "pi-tool", layout, 252).text
    current = "/opt/statehub/hubs/pi-tool/current"
    assert f"ExecStartPre={current}/venv/bin/python -P -m hubs pi-tool --config {current}/hubs.toml --selftest\n" \
        in text
    assert f"ExecStart={current}/venv/bin/python -P -m hubs pi-tool --config {current}/hubs.toml\n" in text
    for line in ("User=statehub", "Restart=always", "RestartSec=5s", "StartLimitIntervalSec=0",
                 "After=network-online.target", "Wants=network-online.target", "NoNewPrivileges=yes",
                 "ProtectSystem=strict", "SupplementaryGroups=i2c", "StandardOutput=journal",
                 "WantedBy=multi-user.target", "Type=notify", "WatchdogSec=10s", "MemoryMax=256M", "TasksMax=64"):
        assert line + "\n" in text, line
    assert "AmbientCapabilities" not in text and "RestartSteps" not in text
    newer = hub_unit(station, "pi-tool", layout, BACKOFF_SYSTEMD).text
    assert "RestartSteps=" in newer and "RestartMaxDelaySec=60s" in newer


def test_device_groups_only_for_real_hardware(station):
    assert "SupplementaryGroups=dialout\n" in hub_unit(station, "rfidcam").text
    for hub in ("pi-rsp", "pi-dock", "ur10", "agv"):  # emulated or network devices: no groups
        assert "SupplementaryGroups" not in hub_unit(station, hub).text


def test_controller_unit_keeps_its_state_in_var_lib(station):
    text = controller_unit(station).text
    assert "ExecStart=/opt/statehub/controller/current/venv/bin/python -P -m controller --config " \
           "/opt/statehub/controller/current/hubs.toml\n" in text
    assert "StateDirectory=statehub statehub/var\n" in text  # [controller] db = var/controller.sqlite
    assert "WorkingDirectory=%S/statehub\n" in text and "ExecStartPre" not in text
    for line in ("Type=notify", "WatchdogSec=30s", "MemoryMax=2G", "TasksMax=256"):
        assert line + "\n" in text, line


def test_unknown_hub_is_named_with_the_file():
    with pytest.raises(KeyError, match=r"hubs.toml: no hub named 'pi-nope' \(hubs: pi-tool"):
        hub_unit(parse_config(station_toml(), "hubs.toml"), "pi-nope")


def test_systemd_version_is_read_from_the_first_line():
    assert parse_systemd_version("systemd 252 (252.38-1~deb12u1)\n+PAM +AUDIT") == 252
    assert parse_systemd_version("no systemd here") is None


def test_units_command_writes_one_unit_per_process(tmp_path):
    config = tmp_path / "hubs.toml"
    config.write_text(station_toml())
    run = hubctl("units", "--config", str(config), "--out", str(tmp_path / "out"), "--systemd-version", "255")
    assert run.code == 0, run.err
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert "statehub-controller.service" in names and "statehub-hub-pi-tool.service" in names
    assert "RestartSteps" in (tmp_path / "out" / "statehub-hub-pi-tool.service").read_text()
    assert "systemd 255 (--systemd-version)" in run.out


def test_config_check_prints_a_summary(tmp_path):
    config = tmp_path / "hubs.toml"
    config.write_text(station_toml())
    run = hubctl("config", "check", "--config", str(config))
    assert run.code == 0, run.err
    assert run.out.startswith(f"{config}: ok\n")
    assert re.search(r"hub pi-tool +pi@pi-tool.local: nr \(nutrunner, emulate\), lift \(lift, emulate\)", run.out)
    assert re.search(r"\d+ hubs serve all \d+ resources of the model", run.out)


def test_config_check_names_file_line_and_key(tmp_path):
    config = tmp_path / "hubs.toml"
    text = station_toml().replace('type = "nutrunner"', 'type = "nutrunnr"').replace(
        "[hubs.pi-rsp]\n", "[hubs.pi-rsp]\nrate_hz = -1\n")
    config.write_text(text)
    run = hubctl("config", "check", "--config", str(config))
    assert run.code == 1
    lines = text.splitlines()
    type_line = lines.index('type = "nutrunnr"') + 1
    rate_line = lines.index("rate_hz = -1") + 1
    assert f"{config}:{type_line}: hubs.pi-tool.devices.nr.type: unknown device type 'nutrunnr'" in run.err
    assert f"{config}:{rate_line}: hubs.pi-rsp.rate_hz:" in run.err
    assert run.out == ""


def test_config_check_against_the_model(tmp_path):
    config = tmp_path / "hubs.toml"
    text = station_toml()
    start = text.index("[hubs.pi-dock.devices.dock]")
    config.write_text(text[:start] + text[start:].split("\n", 3)[3])  # nobody serves the dock any more
    run = hubctl("config", "check", "--config", str(config))
    assert run.code == 1
    assert "station.model: resource 'dock' of station model" in run.err and "is served by no hub" in run.err


def test_config_check_of_a_missing_file(tmp_path):
    run = hubctl("config", "check", "--config", str(tmp_path / "nope.toml"))
    assert run.code == 1 and "cannot read" in run.err and "nope.toml" in run.err


def test_rendered_units_also_pass_the_structural_check(tmp_path, station):
    """The fallback must accept what systemd accepts, or CI without systemd-analyze would fail falsely."""
    layout = Layout(str(tmp_path / "root"))
    fake_install(tmp_path, layout, [None, *station.hubs])
    for version in (DEFAULT_SYSTEMD, BACKOFF_SYSTEMD):
        for unit in station_units(station, layout, version):
            assert structural_problems(unit.text, version) == [], unit.name
