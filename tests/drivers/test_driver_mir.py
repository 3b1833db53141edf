"""MiR100 driver (REST API v2.0.0) against the simulated MiR REST server."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.mir_rest import MirRest
from hubs.drivers.reconnect import Backoff
from hubs.factory import make_driver
from hubs.sim import mir_rest as sim
from hubs.sim.mir_rest import MirRobot, MirServer
from tests.drivers.drvtest import Connect, Serve, eventually, read_until, simulator_process

REPO = Path(__file__).resolve().parents[2]
FAST = Backoff(initial=0.02, maximum=0.2)


def params(port: int, **extra: Any) -> dict[str, Any]:
    return {"port": port, "reconnect_min": 0.02, "reconnect_max": 0.2, "poll_interval": 0.05, "timeout": 2.0, **extra}


@pytest.fixture
async def mir(serve: Serve) -> MirServer:
    return await serve(MirServer(MirRobot(speed=20.0)))


@pytest.fixture
async def driver(mir: MirServer, connect: Connect) -> MirRest:
    drv = make_driver("mir", "mir", "sim", params(mir.port))
    assert isinstance(drv, MirRest)
    return await connect(drv)


async def test_auth_header_is_the_mir_scheme(mir: MirServer) -> None:
    async with httpx.AsyncClient(base_url=mir.url) as client:
        assert (await client.get("/api/v2.0.0/status")).status_code == 401
        headers = {"Authorization": sim.auth_header("admin", "admin")}
        status = (await client.get("/api/v2.0.0/status", headers=headers)).json()
    assert status["state_id"] == 3 and status["state_text"] == "Ready"


async def test_drive_to_station_and_back(driver: MirRest, mir: MirServer) -> None:
    assert dict(await driver.read()) == {"pos_m": "at_kitting"}
    await driver.write({"goto_c": "station"})
    await read_until(driver, pos_m="moving")
    for _ in range(5):  # the controller re-sends its command: no duplicate missions
        await driver.write({"goto_c": "station"})
    await read_until(driver, pos_m="at_station")
    assert [m for m, p in mir.requests if m == "POST"] == ["POST"]
    await driver.write({"goto_c": "kitting"})
    await read_until(driver, pos_m="at_kitting")


async def test_goto_none_stops_and_resume(driver: MirRest, mir: MirServer) -> None:
    mir.robot.speed = 2.0
    await driver.write({"goto_c": "station"})
    def well_away_from_the_kitting_area() -> bool:
        mir.robot.update()
        return mir.robot.x > 3.0

    await eventually(well_away_from_the_kitting_area)
    assert await driver.enter_safe_state() == {"goto_c": "none"}
    await eventually(lambda: mir.robot.state_id == sim.PAUSE)
    x = mir.robot.x
    await asyncio.sleep(0.2)
    mir.robot.update()
    assert mir.robot.x == x  # stopped
    assert dict(await driver.read()) == {"pos_m": "moving"}  # between the targets
    mir.robot.speed = 50.0
    await driver.write({"goto_c": "station"})
    await read_until(driver, pos_m="at_station")


async def test_robot_vanishes_mid_mission_and_returns(driver: MirRest, mir: MirServer) -> None:
    mir.robot.speed = 2.0
    await driver.write({"goto_c": "station"})
    await read_until(driver, pos_m="moving")
    await mir.stop()
    await eventually(lambda: not driver.connected)
    with pytest.raises(DeviceUnavailable):
        await driver.read()  # never the last known position
    mir.restart_robot()  # it rebooted: the queue is gone
    mir.robot.speed = 50.0
    await mir.start()
    await eventually(lambda: driver.connected)
    await read_until(driver, pos_m="at_station")  # the reference state is driven again
    assert driver.link.connects >= 2


async def test_restarted_hub_adopts_the_running_mission(mir: MirServer) -> None:
    mir.robot.speed = 15.0
    mission = mir.robot.enqueue(sim.STATION_MISSION)
    drv = make_driver("mir", "mir", "sim", params(mir.port))
    await drv.connect()
    try:
        await read_until(drv, pos_m="moving")
        await drv.write({"goto_c": "station"})
        assert [m for m, p in mir.requests if m == "POST"] == []  # adopted, not posted again
        assert mission.state == "Executing"
        await read_until(drv, pos_m="at_station")
    finally:
        await drv.close()


async def test_an_old_status_is_asked_again_not_taken_for_a_lost_robot(driver: MirRest, mir: MirServer) -> None:
    """The hub was starved (its poll loop did not run) for longer than `stale_after`: a read asks the
    robot again instead of dropping the connection, and answers with where the robot is now."""
    await driver.write({"goto_c": "station"})
    await read_until(driver, pos_m="at_station")
    polls = sum(1 for m, p in mir.requests if (m, p) == ("GET", "/api/v2.0.0/status"))
    time.sleep(driver.stale_after + 0.1)  # blocks the loop: no poll, the status ages
    assert dict(await driver.read()) == {"pos_m": "at_station"}
    assert driver.connected and driver.link.connects == 1
    assert sum(1 for m, p in mir.requests if (m, p) == ("GET", "/api/v2.0.0/status")) > polls  # asked again


class PauseRecordingRobot(MirRobot):
    """Counts the times the robot is paused with a mission of its queue pending or under way."""

    missions_paused = 0

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "state_id" and value == sim.PAUSE and any(
                e.state in ("Pending", "Executing") for e in getattr(self, "queue", [])):
            type(self).missions_paused += 1
        super().__setattr__(name, value)


async def test_the_selftest_never_pauses_a_mission_a_command_posts_meanwhile(serve: Serve, connect: Connect) -> None:
    """The hub runs its self-test while commands arrive: its Pause/Ready read-back must not interleave
    with a command that posts a mission (seen in sim mode: at_kitting, moving, at_kitting, moving)."""
    PauseRecordingRobot.missions_paused = 0
    mir = await serve(MirServer(PauseRecordingRobot(speed=2.0)))
    built = make_driver("mir", "mir", "sim", params(mir.port))
    assert isinstance(built, MirRest)
    driver = await connect(built)
    report, _ = await asyncio.gather(driver.selftest(), driver.write({"goto_c": "station"}))
    assert report.ok, report
    await read_until(driver, pos_m="moving")
    assert PauseRecordingRobot.missions_paused == 0


async def test_selftest_passes(driver: MirRest) -> None:
    report = await driver.selftest()
    assert report.ok, report


async def test_selftest_fails_when_robot_absent(mir: MirServer) -> None:
    port = mir.port
    await mir.stop()
    drv = make_driver("mir", "mir", "sim", params(port))
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and str(port) in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_selftest_fails_with_wrong_password_or_unknown_mission(mir: MirServer) -> None:
    drv = make_driver("mir", "mir", "sim", params(mir.port, password="wrong"))
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and "401" in report.checks[0].detail
    finally:
        await drv.close()
    missions = {"kitting": sim.KITTING_MISSION, "station": "00000000-0000-0000-0000-000000000000"}
    drv = make_driver("mir", "mir", "sim", params(mir.port, missions=missions))
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and "station=00000000" in report.checks[0].detail
    finally:
        await drv.close()


async def test_selftest_fails_when_state_not_read_back(driver: MirRest, mir: MirServer) -> None:
    mir.ignore_state_changes = True  # acknowledged, not applied
    report = await driver.selftest()
    assert not report.ok
    failed = [c for c in report.checks if not c.ok]
    assert [c.name for c in failed] == ["outputs read back"] and "4 written, 3 read back" in failed[0].detail


async def test_simulator_as_a_process() -> None:
    async with simulator_process("hubs.sim.mir_rest", "--port", "0", "--speed", "50") as (proc, line):
        drv = make_driver("mir", "mir", "sim", params(int(line.rsplit(":", 1)[1])))
        await drv.connect()
        try:
            assert await drv.link.wait_connected(5)  # type: ignore[attr-defined]  # the driver's link
            await drv.write({"goto_c": "station"})
            await read_until(drv, pos_m="at_station")
            proc.kill()
            proc.wait()
            await eventually(lambda: not drv.connected)
        finally:
            await drv.close()
