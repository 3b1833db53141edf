"""RSP tool changer and tool dock drivers against the Modbus TCP coupler simulator."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.dock_modbus import DockModbus
from hubs.drivers.reconnect import Backoff
from hubs.drivers.rsp_modbus import RspModbus
from hubs.factory import make_driver
from hubs.sim.toolchanger_modbus import ToolChangerPhysics, ToolChangerServer
from tests.drivers.drvtest import Connect, Serve, eventually, read_until, simulator_process

REPO = Path(__file__).resolve().parents[2]
FAST = Backoff(initial=0.02, maximum=0.2)


@pytest.fixture
async def coupler(serve: Serve) -> ToolChangerServer:
    return await serve(ToolChangerServer(ToolChangerPhysics(stroke_time=0.05)))


@pytest.fixture
async def rsp(coupler: ToolChangerServer, connect: Connect) -> RspModbus:
    return await connect(RspModbus("rsp", host="127.0.0.1", port=coupler.port, timeout=0.5, backoff=FAST))


@pytest.fixture
async def dock(coupler: ToolChangerServer, connect: Connect) -> DockModbus:
    return await connect(DockModbus("dock", host="127.0.0.1", port=coupler.port, timeout=0.5, backoff=FAST))


ALL_HOME = {"nutrunner_home_m": True, "lift_tool_home_m": True, "filter_tool_home_m": True}


async def test_pick_and_place_a_tool(coupler: ToolChangerServer, rsp: RspModbus, dock: DockModbus) -> None:
    assert dict(await rsp.read()) == {"locked_m": False, "tool_m": "none", "pressure_ok_m": True}
    assert dict(await dock.read()) == ALL_HOME
    coupler.physics.move_flange(1)  # robot at the nutrunner's slot
    await rsp.write({"lock_c": True})
    await read_until(rsp, locked_m=True, tool_m="nutrunner")
    assert (await dock.read())["nutrunner_home_m"]  # still in the slot until the robot leaves
    coupler.physics.move_flange(0)
    await read_until(dock, nutrunner_home_m=False, lift_tool_home_m=True)
    assert await rsp.enter_safe_state() == {}  # never drop the tool
    await read_until(rsp, locked_m=True, tool_m="nutrunner")
    coupler.physics.move_flange(1)
    await rsp.write({"lock_c": False})
    await read_until(rsp, locked_m=False, tool_m="none")
    await read_until(dock, **ALL_HOME)


async def test_flange_position_side_channel_over_modbus(coupler: ToolChangerServer, rsp: RspModbus) -> None:
    """A robot simulator tells the coupler simulator where the flange is through holding registers."""
    client = AsyncModbusTcpClient("127.0.0.1", port=coupler.port, retries=0, reconnect_delay=0)
    assert await client.connect()
    try:
        await client.write_register(0, 2, device_id=1)  # at slot 2: lift tool
        await rsp.write({"lock_c": True})
        await read_until(rsp, locked_m=True, tool_m="lift_tool")
        await client.write_register(1, 0, device_id=1)  # air off
        await read_until(rsp, pressure_ok_m=False)
    finally:
        client.close()


async def test_no_air_no_motion(coupler: ToolChangerServer, rsp: RspModbus) -> None:
    coupler.physics.pressure = False
    coupler.physics.move_flange(3)
    await rsp.write({"lock_c": True})  # the solenoid is on, read back ok ...
    await asyncio.sleep(0.2)
    assert dict(await rsp.read()) == {"locked_m": False, "tool_m": "none", "pressure_ok_m": False}  # ... piston still
    coupler.physics.pressure = True
    await read_until(rsp, locked_m=True, tool_m="filter_tool", pressure_ok_m=True)


async def test_coupler_vanishes_mid_lock_and_returns(
    coupler: ToolChangerServer, rsp: RspModbus, dock: DockModbus
) -> None:
    coupler.physics.stroke_time = 0.5
    coupler.physics.move_flange(1)
    await rsp.write({"lock_c": True})
    await coupler.stop()
    with pytest.raises(DeviceUnavailable):
        await rsp.read()
    assert not rsp.connected
    await eventually(lambda: not dock.connected)
    with pytest.raises(DeviceUnavailable):
        await dock.read()  # never a stale value
    coupler.physics.coils = [False] * len(coupler.physics.coils)  # power cycle: outputs off, valve holds
    await coupler.start()
    await eventually(lambda: rsp.connected and dock.connected)
    # the commanded lock is driven again after the reconnect and the lock completes
    await read_until(rsp, locked_m=True, tool_m="nutrunner")
    assert rsp.link.reconnect.connects >= 2


async def test_exception_response_is_unavailable_but_connected(coupler: ToolChangerServer, rsp: RspModbus) -> None:
    coupler.physics.module_error = True
    with pytest.raises(DeviceUnavailable, match="exception 4"):
        await rsp.read()
    assert rsp.connected
    coupler.physics.module_error = False
    assert (await rsp.read())["pressure_ok_m"]


async def test_selftests_pass(rsp: RspModbus, dock: DockModbus) -> None:
    for report in (await rsp.selftest(), await dock.selftest()):
        assert report.ok, report
        assert {c.name for c in report.checks} == {"device answers", "inputs read", "outputs read back"}

async def test_the_selftest_never_undoes_or_fails_on_a_command_written_meanwhile(
        coupler: ToolChangerServer, rsp: RspModbus) -> None:
    """The hub runs its self-test while commands arrive. Its output read-back must not interleave
    with a command: it would report the command's coils as not read back, or write its own over them.
    The command comes at points spread over one self-test's duration."""
    coupler.physics.move_flange(1)
    started = asyncio.get_running_loop().time()
    assert (await rsp.selftest()).ok
    duration = asyncio.get_running_loop().time() - started
    for step in range(16):
        lock = step % 2 == 0
        await rsp.write({"lock_c": not lock})
        await read_until(rsp, locked_m=not lock)

        async def command_later(lock: bool = lock, delay: float = duration * step / 16) -> None:
            await asyncio.sleep(delay)
            await rsp.write({"lock_c": lock})

        report, _ = await asyncio.gather(rsp.selftest(), command_later())
        assert report.ok, (step, report)
        assert await rsp.link.read_coils(0, 2) == [lock, not lock], step  # the command's coils, not the self-test's
        await read_until(rsp, locked_m=lock)


async def test_selftest_fails_when_coupler_absent(coupler: ToolChangerServer) -> None:
    port = coupler.port
    await coupler.stop()
    for drv in (
        RspModbus("rsp", host="127.0.0.1", port=port, timeout=0.2, backoff=FAST),
        DockModbus("dock", host="127.0.0.1", port=port, timeout=0.2, backoff=FAST),
    ):
        await drv.connect()
        try:
            report = await drv.selftest()
            assert not report.ok
            assert not report.checks[0].ok and str(port) in report.checks[0].detail
        finally:
            await drv.close()


async def test_selftest_fails_when_output_not_read_back(coupler: ToolChangerServer, rsp: RspModbus) -> None:
    coupler.physics.stuck_coils = {1: True}  # unlock solenoid output stuck on
    with pytest.raises(DeviceUnavailable, match="not read back"):
        await rsp.write({"lock_c": True})
    report = await rsp.selftest()
    assert not report.ok
    assert [c.name for c in report.checks if not c.ok] == ["outputs read back"]


async def test_hub_restart_never_unlocks(coupler: ToolChangerServer) -> None:
    """A fresh driver (hub restarted) adopts the coils as they are: a held tool stays locked, also when
    the hub enters its safe state at start and writes the initial command (lock_c = false)."""
    coupler.physics = ToolChangerPhysics.holding("lift_tool", stroke_time=0.05)
    drv = make_driver("rsp", "rsp", "sim", {"port": coupler.port, "reconnect_min": 0.02, "timeout": 0.5})
    await drv.connect()
    try:
        assert await drv.enter_safe_state() == {}  # what the hub runtime does at start: nothing moves
        await read_until(drv, locked_m=True, tool_m="lift_tool")
        assert (await drv.selftest()).ok
        await asyncio.sleep(0.1)
        assert (await drv.read())["locked_m"]
        await drv.write({"lock_c": True})  # the controller's first command: lock (read back ok)
        await drv.write({"lock_c": False})  # a later command does unlock
        await read_until(drv, locked_m=False, tool_m="none")
    finally:
        await drv.close()


def test_real_mode_requires_host() -> None:
    with pytest.raises(ValueError, match="'host'"):
        make_driver("rsp", "rsp", "real", {})


async def test_simulator_as_a_process() -> None:
    args = ("--port", "0", "--holding", "filter_tool")
    async with simulator_process("hubs.sim.toolchanger_modbus", *args) as (proc, line):
        port = int(line.rsplit(":", 1)[1])
        drv = make_driver("dock", "dock", "sim", {"port": port, "reconnect_min": 0.02, "timeout": 0.5})
        await drv.connect()
        try:
            await read_until(drv, nutrunner_home_m=True, filter_tool_home_m=False)
            proc.kill()
            proc.wait()
            await eventually(lambda: not drv.connected)
            with pytest.raises(DeviceUnavailable):
                await drv.read()
        finally:
            await drv.close()
