"""ur-rtde itself against the fake controller: RTDEReceiveInterface, and the driver's *real* motion backend.

The real backend is ur-rtde's RTDEControlInterface: it uploads its URScript to port
30003 and then drives it through RTDE input/output registers.  The fake records the
script and emulates that register interface (it cannot run URScript), so moveJ/moveL
(asynchronous), stopJ, stopScript and the script re-upload after a dashboard stop or a
protective stop are exercised end to end; see docs/drivers.md for exactly how far.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterator
from multiprocessing.connection import Connection
from typing import Any

import pytest

from hubs.drivers.ur_rtde import UrRtde
from hubs.factory import make_driver
from tests.drivers.drvtest import Connect, eventually, read_until
from tests.drivers.ur_fake import HOME, FakeUr, ur_params


def _receive_probe(conn: Connection, host: str) -> None:
    """In a spawned process (ur-rtde may abort at exit): read actual_q and two timestamps."""
    import time

    import rtde_receive

    try:
        rx = rtde_receive.RTDEReceiveInterface(host)
        first = rx.getTimestamp()
        time.sleep(0.1)
        conn.send(
            {
                "q": list(rx.getActualQ()),
                "timestamps": (first, rx.getTimestamp()),
                "tcp": list(rx.getActualTCPPose()),
                "safety_mode": rx.getSafetyMode(),
                "robot_mode": rx.getRobotMode(),
                "protective": rx.isProtectiveStopped(),
            }
        )
    except Exception as exc:
        conn.send({"error": repr(exc)})
    os._exit(0)


# An address of this process's own (RTDE's port 30004 is fixed): the suite runs in several
# processes, and a station in sim mode may have its fake on 127.0.0.2.
HOST = f"127.{os.getpid() % 200 + 20}.0.2"


@pytest.fixture(scope="module")
def fake() -> Iterator[FakeUr]:
    robot = FakeUr(HOST).start()
    yield robot
    robot.kill()


def test_rtde_receive_interface_reads_the_fake(fake: FakeUr) -> None:
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_receive_probe, args=(child, HOST))
    proc.start()
    assert parent.poll(15), "no answer from the probe process"
    got: dict[str, Any] = parent.recv()
    proc.join(5)
    assert "error" not in got, got
    assert got["q"] == pytest.approx(fake.command(cmd="state")["q"])
    first, second = got["timestamps"]
    assert second > first > 0
    assert got["robot_mode"] == 7 and got["safety_mode"] == 1 and got["protective"] is False
    assert len(got["tcp"]) == 6
    recipes = fake.command(cmd="state")["recipes"]
    assert "actual_q" in recipes[-1] and "timestamp" in recipes[-1]


@pytest.fixture
async def ur(fake: FakeUr, connect: Connect) -> UrRtde:
    fake.command(cmd="movej", q=HOME, speed=10)  # tests share this fake: start from home
    drv = make_driver("ur", "ur", "sim", ur_params(fake.host, backend="real"))
    assert isinstance(drv, UrRtde)
    return await connect(drv, timeout=15)


async def test_real_backend_moves_through_rtde_control(ur: UrRtde, fake: FakeUr) -> None:
    await read_until(ur, pos_m="home")
    await ur.write({"ref_pos_c": "at_bolt1"})  # moveJ, asynchronous
    await read_until(ur, pos_m="at_bolt1")
    await ur.write({"ref_pos_c": "at_dock"})  # moveL, asynchronous
    await read_until(ur, pos_m="at_dock")
    state = fake.command(cmd="state")
    assert any("def rtde_control" in script for script in state["scripts"])
    assert {1, 3} <= set(state["commands_seen"])  # moveJ and moveL arrived through the input registers


async def test_real_backend_stop_protective_stop_and_script_reupload(ur: UrRtde, fake: FakeUr) -> None:
    await ur.write({"ref_pos_c": "at_bolt1"})
    await read_until(ur, pos_m="at_bolt1")
    await ur.enter_safe_state()  # stopJ + dashboard "stop": the control script ends
    await eventually(lambda: not fake.command(cmd="state")["script_running"])
    await ur.write({"ref_pos_c": "home"})  # the script is uploaded again, then moveJ
    await read_until(ur, pos_m="home")
    uploads = len(fake.command(cmd="state")["scripts"])
    await ur.write({"ref_pos_c": "at_bolt1"})
    await read_until(ur, pos_m="unknown")
    fake.command(cmd="protective_stop")
    await read_until(ur, prot_stop_m=True)
    await ur.unlock_protective_stop()
    await read_until(ur, prot_stop_m=False, pos_m="at_bolt1")  # re-driven: script uploaded again
    assert len(fake.command(cmd="state")["scripts"]) > uploads
    report = await ur.selftest()
    assert report.ok, report
