"""Safety-camera driver (tracker feed, TCP JSON lines) against the simulated tracker."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.camera_tracker import CameraTracker, parse_frame, parse_rects, zone_of
from hubs.drivers.reconnect import Backoff
from hubs.factory import make_driver
from hubs.sim.camera_tracker import CameraTrackerSim
from tests.drivers.drvtest import Connect, Serve, eventually, read_until, simulator_process

REPO = Path(__file__).resolve().parents[2]
FAST = Backoff(initial=0.02, maximum=0.2)
ZONES = {"shared": [[0, 0, 2, 2]], "robot": [[2, 0, 4, 2], [10, 10, 11, 11]]}


@pytest.fixture
async def tracker(serve: Serve) -> CameraTrackerSim:
    return await serve(CameraTrackerSim(rate=50.0))


@pytest.fixture
async def driver(tracker: CameraTrackerSim, connect: Connect) -> CameraTracker:
    return await connect(CameraTracker("cam", host="127.0.0.1", port=tracker.port, zones=ZONES, stale_after=0.3,
                                       backoff=FAST))


def test_zones_and_frames() -> None:
    zones = parse_rects(ZONES)
    assert zone_of(-1, 1, zones) == "outside"
    assert zone_of(1, 1, zones) == "shared"
    assert zone_of(2, 1, zones) == "robot"  # on the border: the more restrictive zone
    assert zone_of(10.5, 10.5, zones) == "robot"
    assert parse_frame(b'{"v": 1, "seq": 1, "t": 0, "people": [{"id": 1, "x": 1, "y": 2}]}\n') == [(1.0, 2.0)]
    for bad in (b"nonsense\n", b'{"v": 2, "people": []}\n', b'{"v": 1, "people": [{"id": 1}]}\n'):
        with pytest.raises(ValueError):
            parse_frame(bad)
    with pytest.raises(ValueError, match="unknown zone"):
        parse_rects({"kitchen": [[0, 0, 1, 1]]})


async def test_operator_walks_through_the_zones(driver: CameraTracker, tracker: CameraTrackerSim) -> None:
    assert dict(await driver.read()) == {"zone_m": "outside"}  # nobody in view
    tracker.set_person(1, -1.0, 1.0)
    await read_until(driver, zone_m="outside")
    tracker.set_person(1, 1.0, 1.0)
    await read_until(driver, zone_m="shared")
    tracker.set_person(2, 3.0, 1.0)  # a second person in the robot zone wins
    await read_until(driver, zone_m="robot")
    tracker.remove_person(2)
    await read_until(driver, zone_m="shared")


async def test_hung_tracker_is_a_lost_device(driver: CameraTracker, tracker: CameraTrackerSim) -> None:
    tracker.set_person(1, 3.0, 1.0)
    tracker.freeze()
    await eventually(lambda: not driver.connected, timeout=5)
    with pytest.raises(DeviceUnavailable):
        await driver.read()  # never the last zone
    tracker.freeze(False)
    await eventually(lambda: driver.connected)
    assert dict(await driver.read()) == {"zone_m": "robot"}


async def test_tracker_vanishes_and_returns(driver: CameraTracker, tracker: CameraTrackerSim) -> None:
    tracker.set_person(1, 1.0, 1.0)
    await read_until(driver, zone_m="shared")
    await tracker.stop()
    await eventually(lambda: not driver.connected)
    with pytest.raises(DeviceUnavailable):
        await driver.read()
    tracker.set_person(1, 3.5, 0.5)
    await tracker.start()
    await read_until(driver, zone_m="robot")
    assert driver.link.connects >= 2


async def test_bad_lines_are_ignored_and_counted(driver: CameraTracker, tracker: CameraTrackerSim) -> None:
    for writer in list(tracker._writers):
        writer.write(b'garbage\n{"v": 7}\n')
    await eventually(lambda: driver.stats["bad_frames"] == 2)
    assert driver.connected and (await driver.read())["zone_m"] == "outside"


async def test_selftest_passes(driver: CameraTracker) -> None:
    report = await driver.selftest()
    assert report.ok, report


async def test_selftest_fails_when_tracker_absent(tracker: CameraTrackerSim) -> None:
    port = tracker.port
    await tracker.stop()
    drv = make_driver("cam", "camera", "sim", {"port": port, "reconnect_min": 0.05})
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and str(port) in report.checks[0].detail
    finally:
        await drv.close()


async def test_selftest_fails_when_tracker_silent(tracker: CameraTrackerSim) -> None:
    tracker.freeze()
    drv = make_driver("cam", "camera", "sim", {"port": tracker.port, "stale_after": 0.2, "reconnect_min": 0.05})
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok and "no tracker frame" in report.checks[0].detail
    finally:
        await drv.close()


async def test_simulator_as_a_process() -> None:
    args = ("--port", "0", "--walk", "4", "--rate", "50")
    async with simulator_process("hubs.sim.camera_tracker", *args) as (proc, line):
        drv = make_driver("cam", "camera", "sim", {"port": int(line.rsplit(":", 1)[1]), "reconnect_min": 0.05})
        await drv.connect()
        try:
            await read_until(drv, zone_m="outside")
            await read_until(drv, zone_m="shared", timeout=10)
            proc.kill()
            proc.wait()
            await eventually(lambda: not drv.connected)
        finally:
            await drv.close()


async def test_a_stalled_event_loop_is_not_taken_for_a_silent_tracker() -> None:
    """Frames that came while the hub's loop was busy (a long GC, a starved process) wait in the socket:
    the tracker is not declared lost for them. The tracker runs in its own process, as on the cell."""
    async with simulator_process("hubs.sim.camera_tracker", "--port", "0", "--rate", "50") as (_, line):
        drv = make_driver("cam", "camera", "sim",
                          {"port": int(line.rsplit(":", 1)[1]), "reconnect_min": 0.05, "stale_after": 0.3})
        await drv.connect()
        try:
            await read_until(drv, zone_m="outside")
            for _ in range(3):
                time.sleep(0.45)  # the loop stalls; the tracker keeps sending
                assert dict(await drv.read()) == {"zone_m": "outside"}
        finally:
            await drv.close()
