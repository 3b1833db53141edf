"""UR driver (worker process with ur-rtde) against the fake controller, simulated motion backend."""

from __future__ import annotations

import asyncio
import itertools
import os
import time
from collections.abc import Iterator

import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.ur_rtde import Pose, UrRtde, rotation_between
from hubs.factory import make_driver
from tests.drivers.drvtest import Connect, eventually, read_until
from tests.drivers.ur_fake import HOME, POSES, FakeUr, ur_params

# A loopback address per fake (RTDE and dashboard ports are fixed); the second octet keeps concurrent
# test runs on one machine apart.
_hosts = (f"127.{os.getpid() % 200 + 20}.0.{n}" for n in itertools.count(10))


@pytest.fixture
def fake() -> Iterator[FakeUr]:
    robot = FakeUr(next(_hosts)).start()
    yield robot
    robot.kill()


@pytest.fixture
async def ur(fake: FakeUr, connect: Connect) -> UrRtde:
    drv = make_driver("ur", "ur", "sim", ur_params(fake.host))
    assert isinstance(drv, UrRtde)
    return await connect(drv, timeout=15)


def test_pose_table_and_orientation_math() -> None:
    assert Pose.parse("p", {"q": HOME}).kind == "joint"
    assert Pose.parse("p", {"tcp": [0, 0, 0, 0, 0, 1]}).kind == "tcp"
    with pytest.raises(ValueError):
        Pose.parse("p", {"q": HOME, "tcp": HOME})
    with pytest.raises(ValueError):
        Pose.parse("p", {"q": [0, 1]})
    assert rotation_between([0, 0, 0], [0, 0, 0.5]) == pytest.approx(0.5)
    assert rotation_between([0, 3.14159, 0], [0, -3.14159, 0]) == pytest.approx(0, abs=1e-4)  # same rotation


async def test_moves_between_named_poses(ur: UrRtde, fake: FakeUr) -> None:
    assert dict(await ur.read()) == {"pos_m": "home", "prot_stop_m": False}
    fake.command(cmd="movej", q=[0.3, -1.2, 1.2, -1.5, -1.5, 0.2], speed=3)
    await read_until(ur, pos_m="unknown")  # between named poses
    await ur.write({"ref_pos_c": "at_bolt1"})
    await read_until(ur, pos_m="at_bolt1")
    await ur.write({"ref_pos_c": "at_dock"})  # a TCP target
    await read_until(ur, pos_m="at_dock")
    state = fake.command(cmd="state")
    assert state["tcp"][:3] == pytest.approx([0.5, -0.3, 0.4], abs=0.005)
    for _ in range(3):
        await ur.write({"ref_pos_c": "home"})  # repeated at the command rate: one move
    await read_until(ur, pos_m="home")
    with pytest.raises(ValueError, match="unknown pose"):
        await ur.write({"ref_pos_c": "nowhere"})


async def test_protective_stop_reported_and_unlocked(fake: FakeUr) -> None:
    ur = make_driver("ur", "ur", "sim", ur_params(fake.host, joint_speed=0.6))  # 1 s to at_bolt1
    assert isinstance(ur, UrRtde)
    await ur.connect()
    try:
        assert await ur.link.wait_connected(15)
        await ur.write({"ref_pos_c": "at_bolt1"})
        await read_until(ur, pos_m="unknown")
        fake.command(cmd="protective_stop")  # a collision half way
        values = await read_until(ur, prot_stop_m=True)
        assert values["pos_m"] == "unknown"
        assert "Protective stop releasing" in await ur.unlock_protective_stop()
        await read_until(ur, prot_stop_m=False)
        await read_until(ur, pos_m="at_bolt1")  # the reference state is driven again after the unlock
    finally:
        await ur.close()


async def test_safe_state_stops_the_robot_and_keeps_the_reference(ur: UrRtde, fake: FakeUr) -> None:
    await ur.write({"ref_pos_c": "at_bolt1"})
    await eventually(lambda: fake.command(cmd="state")["moving"])
    assert await ur.enter_safe_state() == {}
    await eventually(lambda: not fake.command(cmd="state")["moving"])
    q = fake.command(cmd="state")["q"]
    await asyncio.sleep(0.5)  # held: no re-issue while the controller is silent
    assert fake.command(cmd="state")["q"] == q
    await ur.write({"ref_pos_c": "at_bolt1"})  # the controller is back
    await eventually(lambda: fake.command(cmd="state")["q"][0] == pytest.approx(0.6))


async def test_hub_start_never_moves_the_robot(fake: FakeUr) -> None:
    """The hub starts in the safe state and writes nothing else: the robot stays put until a command."""
    fake.command(cmd="movej", q=[0.6, -1.5708, 1.5708, -1.5708, -1.5708, 0.0], speed=10)
    drv = make_driver("ur", "ur", "sim", ur_params(fake.host))
    assert isinstance(drv, UrRtde)
    await drv.connect()
    try:
        assert await drv.enter_safe_state() == {}  # what the hub runtime does at start
        assert await drv.link.wait_connected(15)
        await read_until(drv, pos_m="at_bolt1")
        await asyncio.sleep(0.5)
        assert not fake.command(cmd="state")["moving"]
        assert (await drv.read())["pos_m"] == "at_bolt1"
        await drv.write({"ref_pos_c": "home"})  # the controller's first command
        await read_until(drv, pos_m="home")
    finally:
        await drv.close()


async def test_controller_killed_then_restarted(ur: UrRtde, fake: FakeUr) -> None:
    await ur.write({"ref_pos_c": "at_bolt1"})
    await read_until(ur, pos_m="at_bolt1")
    old_pid = ur.worker_pid
    fake.kill()
    await eventually(lambda: not ur.connected, timeout=5)
    with pytest.raises(DeviceUnavailable):
        await ur.read()  # ur-rtde's stale getters never reach the controller
    fake.start()  # a fresh controller: the robot stands at home again
    await eventually(lambda: ur.connected, timeout=15)
    assert ur.worker_pid != old_pid  # a new worker process
    await read_until(ur, pos_m="at_bolt1")  # the reference is driven again


async def test_silent_controller_is_lost(ur: UrRtde, fake: FakeUr) -> None:
    fake.command(cmd="freeze", on=True)  # connections open, no RTDE data: timestamps stop
    await eventually(lambda: not ur.connected, timeout=5)
    assert "timestamp" in ur.link.last_error or "silent" in ur.link.last_error or "connect" in ur.link.last_error
    with pytest.raises(DeviceUnavailable):
        await ur.read()
    fake.command(cmd="freeze", on=False)
    await eventually(lambda: ur.connected, timeout=15)
    assert (await ur.read())["pos_m"] == "home"


async def test_a_starved_hub_does_not_blame_its_worker(ur: UrRtde) -> None:
    """The hub's own loop stalls (a starved process) longer than `stale_after` while the worker keeps
    sending: the states waiting in the pipe are taken before staleness is judged."""
    await ur.read()
    time.sleep(3 * ur.stale_after)  # blocks the loop; the worker's states queue up in the pipe
    assert dict(await ur.read())["pos_m"] == "home"
    assert ur.connected and ur.link.connects == 1


async def test_the_selftest_never_sends_back_a_robot_a_command_moves(fake: FakeUr) -> None:
    """The hub runs its self-test while commands arrive: its zero-length move must not interleave with a
    commanded move (the robot would be sent back to where it stood when the check began)."""
    ur = make_driver("ur", "ur", "sim", ur_params(fake.host, joint_speed=0.6, reissue_after=5.0))
    assert isinstance(ur, UrRtde)
    await ur.connect()
    try:
        assert await ur.link.wait_connected(15)
        report, _ = await asyncio.gather(ur.selftest(), ur.write({"ref_pos_c": "at_bolt1"}))
        assert report.ok, report
        state = fake.command(cmd="state")  # 1 s to at_bolt1: still on its way, or there
        bolt1 = POSES["at_bolt1"]["q"]
        assert state["target"] == pytest.approx(bolt1) or state["q"] == pytest.approx(bolt1), state
    finally:
        await ur.close()


async def test_selftest_passes(ur: UrRtde) -> None:
    report = await ur.selftest()
    assert report.ok, report
    assert "RUNNING" in report.checks[0].detail


async def test_selftest_fails_without_controller() -> None:
    drv = make_driver("ur", "ur", "sim", ur_params("127.0.0.9", start_timeout=3.0))
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and "127.0.0.9" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_selftest_fails_in_local_control(fake: FakeUr, ur: UrRtde) -> None:
    fake.command(cmd="remote_control", on=False)
    report = await ur.selftest()
    assert not report.ok
    failed = [c for c in report.checks if not c.ok]
    assert [c.name for c in failed] == ["outputs read back"] and "local control" in failed[0].detail
    with pytest.raises(DeviceUnavailable, match="refused"):
        await ur.write({"ref_pos_c": "at_bolt1"})
