"""Lift driver (CAN) against the simulated lift on python-can's virtual bus."""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Iterator

import can
import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.lift_can import LiftCan
from hubs.drivers.reconnect import Backoff
from hubs.factory import make_driver
from hubs.sim.lift_can import LiftSim
from tests.drivers.drvtest import Connect, eventually, read_until

FAST = Backoff(initial=0.02, maximum=0.2)
_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    return f"test-lift-{next(_channels)}"


@pytest.fixture
def lift(channel: str) -> Iterator[LiftSim]:
    sim = LiftSim(channel, speed=2000.0)
    sim.start()
    yield sim
    sim.stop()


def make(channel: str, **kwargs: float) -> LiftCan:
    return LiftCan(
        "lift",
        bus_factory=lambda: can.Bus(interface="virtual", channel=channel),
        where=f"virtual:{channel}",
        backoff=FAST,
        **kwargs,  # type: ignore[arg-type]  # each test passes its keywords
    )


@pytest.fixture
async def driver(channel: str, lift: LiftSim, connect: Connect) -> LiftCan:
    return await connect(make(channel))


async def test_up_and_down(driver: LiftCan, lift: LiftSim) -> None:
    assert dict(await driver.read()) == {"pos_m": "down"}
    await driver.write({"ref_c": "up"})
    await read_until(driver, pos_m="up")
    assert lift.upper and lift.direction == 0
    await driver.write({"ref_c": "down"})
    await read_until(driver, pos_m="down")


async def test_command_keepalive_holds_motion_beyond_the_lift_watchdog(driver: LiftCan, lift: LiftSim) -> None:
    lift.speed, lift.command_timeout = 400.0, 0.3  # a 2 s stroke: needs the command repeated
    await driver.write({"ref_c": "up"})
    await read_until(driver, pos_m="up", timeout=8)


async def test_safe_state_stops_motion_and_keeps_ref(driver: LiftCan, lift: LiftSim) -> None:
    lift.speed = 200.0
    await driver.write({"ref_c": "up"})
    await read_until(driver, pos_m="between")
    assert await driver.enter_safe_state() == {}  # ref_c keeps its value, the lift stops
    await eventually(lambda: lift.direction == 0 and lift.last_command == 0)
    position = lift.position
    await asyncio.sleep(0.3)  # the stop is repeated: it stays stopped
    assert lift.position == position and lift.direction == 0
    lift.speed = 2000.0
    await driver.write({"ref_c": "up"})  # the controller is back: its first command resumes
    await read_until(driver, pos_m="up")


async def test_the_first_command_after_the_safe_state_moves_at_once(driver: LiftCan, lift: LiftSim) -> None:
    await read_until(driver, pos_m="down")
    assert await driver.enter_safe_state() == {}
    await driver.write({"ref_c": "up"})  # no write after the safe state is taken for the hub's own
    await read_until(driver, pos_m="up")


async def test_device_vanishes_mid_motion_and_returns(driver: LiftCan, lift: LiftSim) -> None:
    lift.speed = 200.0
    await driver.write({"ref_c": "up"})
    await read_until(driver, pos_m="between")
    lift.stop()
    await eventually(lambda: not driver.connected)  # lost heartbeat and status
    with pytest.raises(DeviceUnavailable):
        await driver.read()  # never the last known position
    lift.speed = 2000.0
    lift.start()
    await eventually(lambda: driver.connected)
    await read_until(driver, pos_m="up")  # the reference state is driven again
    assert driver.link.connects >= 2


async def test_fault_and_preoperational(driver: LiftCan, lift: LiftSim) -> None:
    lift.set_fault(3)
    await eventually(lambda: lift.fault_code == 3)
    with pytest.raises(DeviceUnavailable, match="fault code 3"):
        await _read_fault(driver)
    lift.set_fault(0)
    lift.preoperational = True
    await eventually(lambda: not driver.connected)


async def _read_fault(driver: LiftCan) -> None:
    for _ in range(100):
        await driver.read()
        await asyncio.sleep(0.01)


async def test_selftest_passes(driver: LiftCan) -> None:
    report = await driver.selftest()
    assert report.ok, report
    assert [c.name for c in report.checks] == ["device answers", "inputs read", "outputs read back"]


async def test_the_selftest_read_back_holds_while_commands_are_sent_meanwhile(channel: str, lift: LiftSim,
                                                                              connect: Connect) -> None:
    """The hub runs its self-test while commands arrive, and the keepalive resends the command in force:
    the echo of a later command also shows the outputs read back, not a failure."""
    driver = await connect(make(channel, command_period=0.002))
    for step in range(6):

        async def command_later(ref: str = ("up", "down")[step % 2], delay: float = 0.002 * step) -> None:
            await asyncio.sleep(delay)
            await driver.write({"ref_c": ref})

        report, _ = await asyncio.gather(driver.selftest(), command_later())
        assert report.ok, (step, report)


async def test_a_stalled_event_loop_is_not_taken_for_a_silent_lift(driver: LiftCan, lift: LiftSim) -> None:
    """Status frames that arrived while the hub's loop was busy (a long GC, a starved process) are
    waiting to be handed over: the lift is not declared lost for them."""
    await driver.read()
    for _ in range(3):
        time.sleep(3 * driver.status_timeout)  # the loop stalls; the lift keeps sending
        assert dict(await driver.read()) == {"pos_m": "down"}
    assert driver.link.connects == 1


async def test_a_silent_lift_is_still_declared_lost(driver: LiftCan, lift: LiftSim) -> None:
    await driver.read()
    lift.stop()
    await asyncio.sleep(3 * driver.status_timeout)
    with pytest.raises(DeviceUnavailable, match=r"no status frame|no heartbeat"):
        await driver.read()


async def test_selftest_fails_without_device(channel: str) -> None:
    drv = make(channel, heartbeat_timeout=0.2)
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok
        assert "no heartbeat" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_selftest_fails_when_command_not_echoed(driver: LiftCan, lift: LiftSim) -> None:
    lift.ignore_commands = True
    report = await driver.selftest()
    assert not report.ok
    assert [c.name for c in report.checks if not c.ok] == ["outputs read back"]


async def test_factory_sim_mode_starts_the_simulated_lift() -> None:
    params = {"channel": "factory-lift", "sim_speed": 3000, "reconnect_min": 0.02}
    drv = make_driver("lift", "lift", "sim", params)
    await drv.connect()
    try:
        assert (await drv.selftest()).ok
        await drv.write({"ref_c": "up"})
        await read_until(drv, pos_m="up")
    finally:
        await drv.close()
        from hubs.sim.lift_can import ensure_lift

        ensure_lift("factory-lift").stop()


async def test_real_mode_without_can_interface_reports_unavailable() -> None:
    drv = make_driver("lift", "lift", "real", {"interface": "socketcan", "channel": "can9", "reconnect_min": 0.05})
    assert isinstance(drv, LiftCan) and "can9" in drv.where
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and "can9" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()
