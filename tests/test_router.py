"""`hubctl router`: a Zenoh router session configured from line.toml, its systemd unit, and a station whose
processes are all clients of a router running to completion through it (real processes)."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_config
from common.line.config import load_line
from common.wire.ctl import StatusMessage
from common.wire.messages import MessageError
from controller.console.statusview import StatusFollower
from deploy.line.processes import router_child, station_children
from deploy.local.supervisor import Supervisor
from deploy.remote.restart_policy import UP_RESTART
from deploy.remote.units import DEFAULT_SYSTEMD, local_systemd_version, router_unit, write_units
from deploy.router.config import line_router_config, router_zenoh_config
from tests.line_station.site import write_line
from tests.test_units import unit_problems

ROOT = Path(__file__).resolve().parents[1]


def test_router_config_is_a_router_with_the_lines_endpoints(tmp_path):
    line = load_line(write_line(tmp_path, 2))
    config = line_router_config(line, "r2")
    assert json.loads(config.get_json("mode")) == "router"
    assert json.loads(config.get_json("listen/endpoints")) == list(line.routers["r2"].listen)
    assert json.loads(config.get_json("connect/endpoints")) == list(line.routers["r1"].listen)
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("transport/link/tx/lease")) == line.lease_ms


def test_a_router_without_a_listener_or_an_unknown_router_is_refused(tmp_path):
    with pytest.raises(ValueError, match="listen"):
        router_zenoh_config([], [], 1000)
    line = load_line(write_line(tmp_path, 2))
    with pytest.raises(KeyError, match="no router 'r9'"):
        line_router_config(line, "r9")


def test_router_command_says_what_is_wrong(tmp_path):
    line = write_line(tmp_path, 2)
    result = subprocess.run([sys.executable, "-m", "deploy.router", "--config", str(line), "--name", "nope"],
                            capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert result.returncode == 2
    assert "no router 'nope'" in result.stderr


def test_the_router_unit_loads_cleanly(tmp_path):
    base = tmp_path / "opt" / "router"
    python = base / "current" / "venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text("#!/bin/sh\nexit 0\n")
    python.chmod(0o755)
    version = local_systemd_version() or DEFAULT_SYSTEMD
    unit = router_unit("/etc/statehub/line.toml", "r1", secured=True, base=str(base), systemd_version=version)
    assert "-m deploy.router --config /etc/statehub/line.toml --name r1 --certs" in unit.text
    assert "Type=notify" in unit.text and "WatchdogSec=" in unit.text
    (path,) = write_units([unit], tmp_path / "units")
    assert unit_problems(path, version) == []  # systemd-analyze verify where it is installed


def test_a_router_stops_cleanly_on_sigterm(tmp_path):
    line = write_line(tmp_path, 2)
    process = subprocess.Popen([sys.executable, "-m", "deploy.router", "--config", str(line), "--name", "r1"],
                               cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stderr is not None
        started = process.stderr.readline()
        assert "router r1 of line" in started, started
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=30) == 0
        assert "router r1 stopping" in process.stderr.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


async def wait_for_orders(bus: ZenohBus, follower: StatusFollower, key: str, orders: int,
                          timeout: float) -> StatusMessage:
    statuses = bus.subscribe(key, coalesce=False)
    async with asyncio.timeout(timeout):
        while True:
            sample = await statuses.get()
            try:
                status = await follower.take(sample.payload)
            except MessageError:
                continue
            if status is not None and status.production is not None and status.production.done >= orders:
                return status


async def test_a_station_of_clients_runs_to_completion_through_two_routers(tmp_path):
    """Station s2's processes are clients of router r2; this test's watcher is a client of r1: every status
    it sees crossed the router-to-router link."""
    line = load_line(write_line(tmp_path, 2))
    station = line.stations["s2"]
    assert station.router == "r2"
    run_dir = tmp_path / "run"
    children = [router_child(line, "r1", run_dir), router_child(line, "r2", run_dir),
                *station_children(station, run_dir)]
    controller = children[2]
    controller.first_start_args += ["--orders", "2"]  # this test's station runs its own two orders
    said: list[str] = []
    supervisor = Supervisor(children, UP_RESTART, said.append)
    await supervisor.start()
    try:
        keys = load_config(station.config).keys
        async with ZenohBus(zenoh_config("client", connect=line.router_endpoints("r1"), lease_ms=1000)) as bus:
            status = await wait_for_orders(bus, StatusFollower(bus, keys), keys.ctl("status"), 2, timeout=120)
    finally:
        await supervisor.stop()
    assert status.production is not None
    assert [done.product_id for done in status.production.recent] == ["line_station-00001", "line_station-00002"]
    assert not any(supervisor.restarts.values()), said
    assert "router" in (run_dir / "router-r2.log").read_text()
