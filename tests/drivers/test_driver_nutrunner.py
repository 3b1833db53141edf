"""Nutrunner driver (MCP23017 over I2C) against the register-level simulator."""

from __future__ import annotations

import asyncio

import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.nutrunner_mcp23017 import NutrunnerMcp23017, Pins
from hubs.drivers.reconnect import Backoff
from hubs.factory import make_driver
from hubs.sim import mcp23017 as sim
from hubs.sim.mcp23017 import NutrunnerStation, SimI2CBus
from tests.drivers.drvtest import Connect, eventually, read_until

FAST = Backoff(initial=0.01, maximum=0.1)


@pytest.fixture
def bus() -> SimI2CBus:
    return SimI2CBus()


@pytest.fixture
def station(bus: SimI2CBus) -> NutrunnerStation:
    return bus.add(0x20, NutrunnerStation(seed=1))


@pytest.fixture
async def driver(bus: SimI2CBus, station: NutrunnerStation, connect: Connect) -> NutrunnerMcp23017:
    return await connect(NutrunnerMcp23017("nr", address=0x20, bus_factory=bus.open, backoff=FAST, io_timeout=0.5))


# -- the simulator at register level ---------------------------------------------------


def test_register_map_sequential_and_byte_mode() -> None:
    chip = sim.Mcp23017Sim()
    assert chip.read_block(sim.IODIRA, 2) == [0xFF, 0xFF]  # power-on reset
    chip.write_block(sim.IODIRA, [0xFE, 0xFF])
    chip.write(sim.OLATA, 0x01)
    # sequential read wraps from OLATB (0x15) to IODIRA (0x00)
    assert chip.read_block(sim.OLATA, 4) == [0x01, 0x00, 0xFE, 0xFF]
    assert chip.read(sim.GPIOA) & 1 == 1  # output pin reads its latch
    chip.write(sim.IOCON, sim.IOCON_SEQOP)  # byte mode, BANK=0: toggles within the A/B pair
    assert chip.read_block(sim.GPIOA, 3) == [chip.gpio(0), chip.gpio(1), chip.gpio(0)]
    chip.write(sim.IOCON, sim.IOCON_BANK)  # BANK=1: port A 0x00-0x0A, port B 0x10-0x1A
    assert chip.read(0x00) == 0xFE and chip.read(0x10) == 0xFF
    assert chip.read(0x0A) == 0x01  # OLATA in BANK=1
    chip.write(0x05, 0x00)  # IOCON in BANK=1: back to BANK=0
    assert chip.bank == 0 and chip.read(sim.OLATA) == 0x01


def test_bus_raises_remote_io_for_absent_device(bus: SimI2CBus) -> None:
    handle = bus.open()
    with pytest.raises(OSError) as info:
        handle.read_byte_data(0x21, 0)
    assert info.value.errno == 121


def test_tool_physics_run_torque_reset() -> None:
    now = [0.0]
    station = NutrunnerStation(clock=lambda: now[0])
    chip, tool = station.chip, station.tool
    chip.write(sim.IODIRA, 0xFE)
    chip.write(sim.OLATA, 0x01)
    station.tick()
    assert not tool.running
    now[0] = 0.06
    station.tick()
    assert tool.running and not tool.torque_ok
    now[0] = 1.0
    station.tick()
    assert tool.torque_ok and not tool.failed
    chip.write(sim.OLATA, 0x00)
    station.tick()
    now[0] = 1.1
    station.tick()
    assert not (tool.running or tool.torque_ok or tool.failed)


# -- the driver ---------------------------------------------------------------------------


async def test_tightening_cycle(driver: NutrunnerMcp23017) -> None:
    assert dict(await driver.read()) == {"run_m": False, "tqr_m": False, "fail_m": False}
    await driver.write({"run_c": True})
    await read_until(driver, run_m=True)
    await read_until(driver, run_m=True, tqr_m=True, fail_m=False)
    assert await driver.enter_safe_state() == {"run_c": False}  # drives the run output low
    await read_until(driver, run_m=False, tqr_m=False, fail_m=False)


async def test_failed_tightening(bus: SimI2CBus) -> None:
    bus.add(0x21, NutrunnerStation(fail_probability=1.0))
    drv = NutrunnerMcp23017("nr", address=0x21, bus_factory=bus.open, backoff=FAST)
    await drv.connect()
    try:
        assert await drv.link.wait_connected(5)
        await drv.write({"run_c": True})
        await read_until(drv, run_m=True, fail_m=True, tqr_m=False)
    finally:
        await drv.close()


async def test_device_vanishes_mid_tightening_and_returns(
    driver: NutrunnerMcp23017, bus: SimI2CBus, station: NutrunnerStation
) -> None:
    await driver.write({"run_c": True})
    await read_until(driver, run_m=True)
    bus.vanish(0x20)
    with pytest.raises(DeviceUnavailable):
        await driver.read()
    assert not driver.connected  # lost on the first failed read, not after a grace period
    with pytest.raises(DeviceUnavailable):
        await driver.read()  # no stale value
    with pytest.raises(DeviceUnavailable):
        await driver.write({"run_c": True})
    bus.restore(0x20, power_cycled=True)  # registers back at reset values: run output off
    await eventually(lambda: driver.connected)
    # the commanded reference state (run_c = true) is driven again after the reconnect
    assert station.chip.regs[sim.IODIRA] == 0xFE
    await read_until(driver, run_m=True, tqr_m=True)
    assert driver.link.connects >= 2


async def test_brownout_without_bus_error_is_detected(driver: NutrunnerMcp23017, station: NutrunnerStation) -> None:
    await driver.read()
    station.chip.power_on_reset()  # the chip reset silently: IODIR back to all inputs
    with pytest.raises(DeviceUnavailable, match="reset"):
        await driver.read()
    await eventually(lambda: driver.connected)
    assert station.chip.regs[sim.IODIRA] == 0xFE  # reconfigured


async def test_selftest_passes(driver: NutrunnerMcp23017) -> None:
    report = await driver.selftest()
    assert report.ok, report
    assert [c.name for c in report.checks] == ["device answers", "inputs read", "outputs read back"]


async def test_the_selftest_never_undoes_a_command_written_meanwhile(
        driver: NutrunnerMcp23017, station: NutrunnerStation) -> None:
    """The hub runs its self-test while commands arrive: a stop (or start) written meanwhile must not be
    overwritten by the self-test's latch write-back. The command comes at points over one self-test."""
    for step in range(40):
        run = step % 2 == 1
        await driver.write({"run_c": not run})

        async def command_later(run: bool = run, yields: int = step // 2) -> None:
            for _ in range(yields):
                await asyncio.sleep(0)
            await driver.write({"run_c": run})

        report, _ = await asyncio.gather(driver.selftest(), command_later())
        assert report.ok, (step, report)
        assert bool(station.chip.regs[sim.OLATA] & 1) == run, step  # the command's latch, not the self-test's


async def test_selftest_fails_when_device_absent(bus: SimI2CBus) -> None:
    drv = NutrunnerMcp23017("nr", address=0x27, bus_factory=bus.open, backoff=FAST, io_timeout=0.2)
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok
        assert not report.checks[0].ok and "0x27" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_selftest_fails_when_output_not_read_back(driver: NutrunnerMcp23017, station: NutrunnerStation) -> None:
    station.chip.short(0, 0, True)  # run pin shorted to 24 V: level 1 while the latch is 0
    report = await driver.selftest()
    assert not report.ok
    failed = [c for c in report.checks if not c.ok]
    assert [c.name for c in failed] == ["outputs read back"]
    assert "pin level 1" in failed[0].detail
    with pytest.raises(DeviceUnavailable, match="not read back"):
        await driver.write({"run_c": False})


async def test_expander_that_ignores_writes_never_connects(bus: SimI2CBus) -> None:
    station = bus.add(0x22, NutrunnerStation())
    station.chip.ignore_writes = True
    drv = NutrunnerMcp23017("nr", address=0x22, bus_factory=bus.open, backoff=FAST)
    await drv.connect()
    try:
        assert not await drv.link.wait_connected(0.5)
        assert "not read back" in drv.link.last_error
    finally:
        await drv.close()


async def test_custom_pins_and_active_low(bus: SimI2CBus) -> None:
    wiring = sim.Wiring(run=(1, 7), running=(0, 1), torque_ok=(0, 2), fail=(0, 3))
    bus.add(0x23, NutrunnerStation(wiring=wiring))
    pins = Pins(run=(1, 7), running=(0, 1), torque_ok=(0, 2), fail=(0, 3))
    drv = NutrunnerMcp23017("nr", address=0x23, bus_factory=bus.open, pins=pins, backoff=FAST)
    await drv.connect()
    try:
        assert await drv.link.wait_connected(5)
        await drv.write({"run_c": True})
        await read_until(drv, run_m=True, tqr_m=True)
    finally:
        await drv.close()


async def test_real_smbus_without_device_reports_unavailable() -> None:
    drv = make_driver("nr", "nutrunner", "real", {"bus": 97, "address": 0x20, "reconnect_min": 0.05})
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok
        assert "bus 97" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_factory_sim_mode_starts_in_process_simulator() -> None:
    drv = make_driver("nr", "nutrunner", "sim", {"bus": 42, "address": 0x20, "reconnect_min": 0.01})
    await drv.connect()
    try:
        assert (await drv.selftest()).ok
        await drv.write({"run_c": True})
        await read_until(drv, tqr_m=True)
        station = sim.ensure_nutrunner(42, 0x20)
        assert station.tool.cycles == 1
    finally:
        await drv.close()
