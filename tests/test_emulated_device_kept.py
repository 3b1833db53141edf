"""An emulated device outlives its hub, as a real one does (hubs/drivers/emulated.py): a restarted hub finds the
robot where the killed one left it, not at home, so the controller's next command moves nothing and no work is
done twice. Across real processes: the hub is killed with SIGKILL and started again on the same file."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest

from common.config.hubs_toml import load_station
from common.stations import load_model
from deploy.local.station import EMULATED_STATE, Options, child_commands
from hubs.drivers.emulated import EmulatedDriver

REFERENCE = "common.stations.engine_assembly:build_model"
ROOT = Path(__file__).resolve().parents[1]
MOVE_WAIT_S = 5.0


async def robot_at(driver: EmulatedDriver, pose: str) -> None:
    async with asyncio.timeout(MOVE_WAIT_S):
        while (await driver.read())["pos_m"] != pose:
            await asyncio.sleep(0.01)


async def test_a_restarted_hub_finds_the_robot_where_it_was(tmp_path: Path) -> None:
    model = load_model(REFERENCE)
    kept = tmp_path / "ur.json"
    first = EmulatedDriver(model, "ur", speed=10.0, keep_in=kept)
    await first.connect()
    await first.write({"ref_pos_c": "above_engine"})
    await robot_at(first, "above_engine")
    await first.close()  # the file is all a SIGKILL leaves behind: it is written at each change, not at close

    again = EmulatedDriver(model, "ur", speed=10.0, keep_in=kept)
    assert await again.read() == {"pos_m": "above_engine", "prot_stop_m": False}
    assert again.values["ur.ref_pos_c"] == "above_engine"
    await again.connect()
    await again.write({"ref_pos_c": "above_engine"})  # the controller's command, sent again: nothing moves
    await asyncio.sleep(0.2)
    assert (await again.read())["pos_m"] == "above_engine"
    await again.close()

    fresh = EmulatedDriver(model, "ur", speed=10.0)  # without a file: the model's initial values, as before
    assert (await fresh.read())["pos_m"] == "home"


@pytest.mark.parametrize("content", [b"{not json", b"[1, 2]", b'{"ur.pos_m": "on_the_moon"}', b'{"agv.pos_m": "x"}'])
def test_unreadable_kept_values_start_the_device_afresh_and_say_so(
        tmp_path: Path, content: bytes, caplog: pytest.LogCaptureFixture) -> None:
    kept = tmp_path / "ur.json"
    kept.write_bytes(content)
    with caplog.at_level(logging.WARNING, logger="statehub.hub.emulated"):
        driver = EmulatedDriver(load_model(REFERENCE), "ur", keep_in=kept)
    assert driver.values["ur.pos_m"] == "home"
    assert "starts afresh" in caplog.text and str(kept) in caplog.text


def test_hubctl_up_gives_every_hub_its_run_directorys_device_file() -> None:
    config, _ = load_station(ROOT / "hubs.toml")
    options = Options(config=str(ROOT / "hubs.toml"), run_dir=Path("/tmp/run"))
    hubs = [child for child in child_commands(config, options, 7447) if child.name != "controller"]
    assert hubs and all(child.argv[child.argv.index("--emulated-state") + 1] == f"/tmp/run/{EMULATED_STATE}"
                        for child in hubs)


def test_a_hub_killed_and_started_again_finds_its_device_as_it_left_it(tmp_path: Path) -> None:
    """The hub process for the robot, without a controller: its driver is commanded through the kept file's
    neighbour, the running process. Here the move is made by one hub process, which is then SIGKILLed; the next
    process on the same directory publishes the pose it left."""
    devices = tmp_path / EMULATED_STATE
    devices.mkdir()
    (devices / "ur.json").write_bytes(msgspec.json.encode({"ur.ref_pos_c": "above_engine", "ur.pos_m": "above_engine",
                                                           "ur.prot_stop_m": False}))
    probe = (
        "import asyncio, sys\n"
        "from pathlib import Path\n"
        "from common.config.hubs_toml import load_station\n"
        "from hubs.factory import build_drivers\n"
        f"config, model = load_station({str(ROOT / 'hubs.toml')!r})\n"
        f"drivers = build_drivers(config, 'ur10', model, emulated_state=Path({str(devices)!r}))\n"
        "ur = drivers['ur']\n"
        "async def main():\n"
        "    await ur.connect()\n"
        "    await ur.write({'ref_pos_c': 'at_bolt1'})\n"
        "    while (await ur.read())['pos_m'] != 'at_bolt1':\n"
        "        await asyncio.sleep(0.01)\n"
        "    print('at_bolt1', flush=True)\n"
        "    await asyncio.sleep(60)\n"
        "asyncio.run(main())\n"
    )
    mover = subprocess.Popen([sys.executable, "-c", probe], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert mover.stdout is not None and mover.stdout.readline().strip() == "at_bolt1"
        os.kill(mover.pid, signal.SIGKILL)
    finally:
        mover.wait(timeout=10)
    reader = (
        "from pathlib import Path\n"
        "from common.config.hubs_toml import load_station\n"
        "from hubs.factory import build_drivers\n"
        f"config, model = load_station({str(ROOT / 'hubs.toml')!r})\n"
        f"drivers = build_drivers(config, 'ur10', model, emulated_state=Path({str(devices)!r}))\n"
        "print(drivers['ur'].values['ur.pos_m'], drivers['ur'].values['ur.ref_pos_c'])\n"
    )
    after = subprocess.run([sys.executable, "-c", reader], cwd=ROOT, capture_output=True, text=True, timeout=60,
                           check=True)
    assert after.stdout.split() == ["at_bolt1", "at_bolt1"]
