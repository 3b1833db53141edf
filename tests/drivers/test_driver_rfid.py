"""RFID reader driver (EM4100 frames over serial) against the simulated reader on a pty pair."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import pytest

from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.reconnect import Backoff
from hubs.drivers.rfid_serial import RfidSerial, parse_body
from hubs.factory import make_driver
from hubs.sim.rfid_serial import RfidReaderSim, frame
from tests.drivers.drvtest import Connect, eventually, read_until, simulator_process

REPO = Path(__file__).resolve().parents[2]
FAST = Backoff(initial=0.02, maximum=0.2)
ALICE, BOB, MALLORY = "0A1B2C3D4E", "1122334455", "DEADBEEF00"


@pytest.fixture
def reader(tmp_path: Path) -> Iterator[RfidReaderSim]:
    with RfidReaderSim(tmp_path / "rfid0") as sim:
        yield sim


@pytest.fixture
async def driver(reader: RfidReaderSim, connect: Connect) -> RfidSerial:
    return await connect(RfidSerial("rfid", port=reader.path, operators={ALICE: "alice", BOB: "bob"},
                                    repeat_window=0.2, backoff=FAST))


def test_frame_format() -> None:
    data = frame("0A1B2C3D4E")
    assert data[0] == 0x02 and data[-1] == 0x03 and data[-3:-1] == b"\r\n" and len(data) == 16
    assert data[11:13] == f"{0x0A ^ 0x1B ^ 0x2C ^ 0x3D ^ 0x4E:02X}".encode()
    assert parse_body(data[1:-1]) == "0A1B2C3D4E"
    assert parse_body(frame("0A1B2C3D4E", corrupt=True)[1:-1]) is None
    assert parse_body(b"0A1B2C3D4Z00\r\n") is None


async def test_badge_in_and_out(driver: RfidSerial, reader: RfidReaderSim) -> None:
    assert dict(await driver.read()) == {"verified_m": False}
    reader.scan(ALICE, repeats=3)  # one presentation, repeated by the reader
    await read_until(driver, verified_m=True)
    assert driver.operator == "alice"
    await eventually(lambda: driver.stats["frames"] == 3)
    assert driver.stats["logins"] == 1
    await asyncio.sleep(0.3)  # past the repeat window
    reader.scan(BOB)  # another operator takes over: still verified
    await eventually(lambda: driver.operator == "bob")
    await asyncio.sleep(0.3)
    reader.scan(BOB)  # badge out
    await read_until(driver, verified_m=False)


async def test_unknown_and_corrupted_frames_are_ignored_and_counted(driver: RfidSerial, reader: RfidReaderSim) -> None:
    reader.scan(MALLORY)
    reader.send_corrupted(ALICE)
    reader.send_raw(b"\x00noise")
    reader.send_raw(b"\x020A1B\x02" + frame(BOB)[1:])  # truncated frame followed by a good one
    await eventually(lambda: driver.stats["rejected"] == 1 and driver.stats["bad_frames"] == 2)
    await eventually(lambda: driver.operator == "bob")
    assert driver.stats["noise_bytes"] >= 6


async def test_session_timeout(reader: RfidReaderSim) -> None:
    drv = RfidSerial("rfid", port=reader.path, operators=[ALICE], session_timeout=0.3, backoff=FAST)
    await drv.connect()
    try:
        assert await drv.link.wait_connected(5)
        reader.scan(ALICE)
        await read_until(drv, verified_m=True)
        await read_until(drv, verified_m=False, timeout=3)
    finally:
        await drv.close()


async def test_reader_unplugged_and_replugged(driver: RfidSerial, reader: RfidReaderSim) -> None:
    reader.scan(ALICE)
    await read_until(driver, verified_m=True)
    reader.stop()  # EIO on the driver's side of the pty
    await eventually(lambda: not driver.connected)
    with pytest.raises(DeviceUnavailable):
        await driver.read()
    reader.start()  # a new pty; the stable link points at it
    await eventually(lambda: driver.connected)
    assert dict(await driver.read()) == {"verified_m": False}  # a lost reader logs out
    reader.scan(ALICE)
    await read_until(driver, verified_m=True)
    assert driver.link.connects >= 2


async def test_selftest_passes(driver: RfidSerial) -> None:
    report = await driver.selftest()
    assert report.ok, report


async def test_selftest_fails_when_port_absent(tmp_path: Path) -> None:
    drv = make_driver("rfid", "rfid", "real", {"serial_port": str(tmp_path / "ttyUSB9"), "reconnect_min": 0.05})
    await drv.connect()
    try:
        report = await drv.selftest()
        assert not report.ok
        assert "ttyUSB9" in report.checks[0].detail
        with pytest.raises(DeviceUnavailable):
            await drv.read()
    finally:
        await drv.close()


async def test_simulator_as_a_process(tmp_path: Path) -> None:
    link = tmp_path / "rfid-proc"
    async with simulator_process("hubs.sim.rfid_serial", "--link", str(link), stdin=True) as (proc, line):
        assert proc.stdin is not None and line == str(link)
        drv = make_driver("rfid", "rfid", "sim", {"serial_port": str(link), "operators": [ALICE]})
        await drv.connect()
        try:
            assert await drv.link.wait_connected(5)  # type: ignore[attr-defined]  # the driver's link
            proc.stdin.write(ALICE + "\n")
            proc.stdin.flush()
            await read_until(drv, verified_m=True)
        finally:
            await drv.close()
