"""Sim mode: every device's real driver against its simulator, the simulators coupled like the real cell.

* the pieces: the robot's pose table, the tool taken by hand, the operator's walk, the
  parameter-override files of `hubctl hub --params-file`;
* `hubctl selftest HUB --mode sim` passes for every hub of hubs.toml while the simulated
  world runs, and fails (non-zero exit) for the hub whose simulator is down;
* the simulated devices follow the reference station's model, driven by the test
  itself (no controller, no planner): each measured trace is what the model's effects
  say (`SimCell`);
* `hubctl up --mode sim` runs a small station (tests/sim_station: the reference story
  with 2 bolts, 1 filter, 1 pipe; every device type) to completion;
* `hubctl up --mode sim` runs the whole reference station of hubs.toml to completion
  (about two minutes), see docs/sim-mode.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.config.hubs_toml import load_station
from common.config.modes import DeviceMode
from common.model import Duration
from common.stations import engine_assembly as ea
from deploy.local.simworld import SimWorld
from deploy.local.station import Options, run_station
from hubs.drivers.emulated import EmulatedDriver
from hubs.factory import build_drivers, load_overrides
from hubs.protocols.coupler import TOOLS
from hubs.protocols.ur import DASHBOARD_PORT, RTDE_PORT
from hubs.sim.cell import Walker
from hubs.sim.toolchanger_modbus import ToolChangerPhysics
from hubs.sim.ur_poses import check_pose_table, pose_table
from hubs.sim.ur_robot import HOME_Q
from tests.sim_station.harness import ROOT, SimCell

REFERENCE = ROOT / "hubs.toml"
SMALL = ROOT / "tests" / "sim_station" / "hubs.toml"


# --- the pieces --------------------------------------------------------------------------------

def test_pose_table_is_deterministic_and_keeps_poses_and_moves_apart() -> None:
    table = pose_table(ea.POSES, ea.ALLOWED_MOVES, ea.HOME)
    assert set(table) == set(ea.POSES)
    assert list(table[ea.HOME]) == HOME_Q  # the fake robot starts at home, as the model does
    assert check_pose_table(table, ea.ALLOWED_MOVES) == []
    assert pose_table(ea.POSES, ea.ALLOWED_MOVES, ea.HOME) == table
    # a pose keeps its target whatever else the station has
    assert pose_table(("home", "at_bolt3"), [("home", "at_bolt3")], "home")["at_bolt3"] == table["at_bolt3"]


def test_operator_takes_a_tool_by_hand_only_from_its_slot() -> None:
    now = [0.0]
    sim = ToolChangerPhysics(clock=lambda: now[0])
    sim.set_hand(1)  # the nutrunner (slot 1)
    assert sim.home("nutrunner") is False and sim.attached is None
    sim.set_hand(0)
    assert sim.home("nutrunner") is True
    # coupled to the robot at its slot: the hand does not take it
    sim.move_flange(1)
    sim.coils[0] = True
    now[0] += 1.0
    sim.update()
    assert sim.attached == "nutrunner"
    sim.set_hand(1)
    assert sim.attached == "nutrunner" and sim.home("nutrunner") is True
    assert sim.in_hand == set()
    assert TOOLS[0] == "nutrunner"


def test_operator_walks_to_the_robot_zone_without_crossing_the_shared_zone() -> None:
    walker = Walker({"shared": [[0.0, 0.0, 2.0, 2.0]], "robot": [[2.0, 0.0, 4.0, 2.0]]}, speed=1.0)
    zones = [walker.zone_at(walker.position)]
    for target in ("robot", "outside", "shared", "outside"):
        walker.go(target)
        for _ in range(200):
            walker.step(0.05)
            zone = walker.zone_at(walker.position)
            if zone != zones[-1]:
                zones.append(zone)
    assert zones == ["outside", "robot", "outside", "shared", "outside"]


def test_params_file_overrides_driver_parameters(tmp_path: Path) -> None:
    config, model = load_station(REFERENCE)
    path = tmp_path / "o.json"
    path.write_text(json.dumps({"nr": {"delay": 0.5, "failure_probability": 1.0}}))
    drivers = build_drivers(config, "pi-tool", model, overrides=load_overrides(path))
    nutrunner = drivers["nr"]
    assert isinstance(nutrunner, EmulatedDriver)
    assert nutrunner.emulator.failure == {"nr": 1.0}
    assert nutrunner.emulator.durations.of_resource("nr") == Duration.fixed(0.5)
    toml = tmp_path / "o.toml"
    toml.write_text('[nr]\ndelay = 0.5\n')
    assert load_overrides(toml) == {"nr": {"delay": 0.5}}
    with pytest.raises(ValueError, match="serves no such resource"):
        build_drivers(config, "pi-tool", model, overrides={"ur": {"host": "x"}})
    (tmp_path / "bad.json").write_text("{nr: 1")
    with pytest.raises(ValueError, match=r"bad.json: invalid JSON"):
        load_overrides(tmp_path / "bad.json")


def test_sim_mode_leaves_devices_without_a_simulator_emulated() -> None:
    config, model = load_station(REFERENCE)
    world = SimWorld(config, model, Path("unused"))
    assert world.emulated == ["agv (agv)", "human (operator)"]
    assert sorted(d.type for d in world.devices.values()) == sorted(
        ["nutrunner", "lift", "rsp", "dock", "mir", "ur", "rfid", "camera"])
    drivers = build_drivers(config, "human", model, mode=DeviceMode.SIM)
    assert type(drivers["human"]).__name__ == "EmulatedDriver"


# --- self-test ---------------------------------------------------------------------------------

# A self-test process needs ~0.5 s of CPU (most of it Python starting up), and the test starts eight at
# once, each UR self-test with a worker process of its own, on a 2-core machine that other test workers
# keep busy: they are slow then, not stuck (the slowest driver check is bounded at ~30 s, see
# UrRtde.selftest). A process over this is killed and reported with what it printed.
SELFTEST_DEADLINE_S = 120.0


async def _selftest(hub: str, world: SimWorld) -> tuple[int, str]:
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "deploy.cli", "selftest", hub, "--config", str(REFERENCE), "--mode", "sim",
        *world.hub_args(hub), cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert process.stdout is not None
    began, out = time.monotonic(), b""
    try:
        async with asyncio.timeout(SELFTEST_DEADLINE_S):
            while chunk := await process.stdout.read(4096):
                out += chunk
            await process.wait()
    except TimeoutError:
        process.kill()
        await process.wait()
        raise AssertionError(f"hubctl selftest {hub} still running after {time.monotonic() - began:.0f} s; "
                             f"it printed:\n{out.decode(errors='replace')}") from None
    return process.returncode or 0, out.decode(errors="replace")


@contextlib.contextmanager
def reserved(*addresses: tuple[str, int]) -> Iterator[None]:
    """TCP addresses bound but not listening while inside: nobody else can serve them, and a client is refused.
    (No SO_REUSEADDR: with it, a server that sets it, as asyncio's do, could still bind the address.) An address
    that cannot be bound (a connection of its own in TIME_WAIT) stays unreserved; the fake UR's scan of the
    addresses from a place of its own already makes another run taking this one unlikely."""
    sockets = []
    try:
        for address in addresses:
            sock = socket.socket()
            sockets.append(sock)
            with contextlib.suppress(OSError):
                sock.bind(address)
        yield
    finally:
        for sock in sockets:
            sock.close()


@pytest.mark.slow
async def test_selftest_passes_for_every_hub_with_the_simulators_and_fails_when_one_is_down(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    config, model = load_station(REFERENCE)
    async with SimWorld(config, model, tmp_path / "sim", say=lambda _line: None) as world:
        results = await asyncio.gather(*(_selftest(hub, world) for hub in config.hubs))
        for hub, (code, out) in zip(config.hubs, results, strict=True):
            assert code == 0, f"self-test of {hub} failed with the simulators running:\n{out}"
            assert "PASS" in out
        down = {"pi-rsp": "coupler-rsp", "mircom": "mir-mir", "ur10": "ur-ur", "rfidcam": "camera-cam"}
        for process in down.values():
            await world.processes[process].stop()
        # The fake UR's fixed ports on its own loopback address: kept bound (not listening: a connection is
        # refused, as by a robot that is off) so that another test's fake cannot take the address meanwhile.
        with reserved((world.processes["ur-ur"].address, RTDE_PORT), (world.processes["ur-ur"].address,
                                                                      DASHBOARD_PORT)):
            results = await asyncio.gather(*(_selftest(hub, world) for hub in down))
        for (hub, process), (code, out) in zip(down.items(), results, strict=True):
            assert code != 0, f"self-test of {hub} passed with its simulator {process} down:\n{out}"
            assert "FAIL" in out


# --- the devices follow the model -----------------------------------------------------------------

@pytest.mark.slow
async def test_simulated_devices_follow_the_reference_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The reference story's device steps, commanded by the test; every trace is the model's."""
    monkeypatch.chdir(ROOT)
    began = time.monotonic()
    async with SimCell(REFERENCE, tmp_path, speed=3.0) as cell:
        await cell.wait("rfid.verified_m", True)  # the simulated operator badged in at start
        assert cell.trace("rfid.verified_m") == [False, True]
        assert cell.values["cam.zone_m"] == "outside" and cell.values["ur.pos_m"] == "home"

        async def step(resource: str, path: str, target: object, expected: list[object], **command: object) -> None:
            since = cell.mark(path)
            cell.command(resource, **command)  # type: ignore[arg-type]  # the table's values
            await cell.wait(path, target)  # type: ignore[arg-type]  # the table's values
            went = cell.trace(path, since)
            assert went == expected, (f"{resource} {command}: {path} went {went} "
                                      f"(longest gap between commands {cell.longest_command_gap:.2f} s)")

        seen_between = 0  # moves whose `unknown` the hub reported

        async def move(pose: str) -> None:
            """The model's move: the start pose, `unknown` while the robot moves, the target, and never another
            pose on the way. The hub samples the robot (50 Hz, through the fake's RTDE stream and the driver's
            worker), so a move of 0.12-0.25 s at this speed can fall between two samples when a process of
            that chain is starved: `unknown` may then be missed, which the system does not promise to show.
            What it does promise is checked: the poses in order, and a pose named only where the robot stands
            (asked of the fake controller itself once the hub names the target)."""
            nonlocal seen_between
            start = cell.trace("ur.pos_m")[-1]  # the last known pose: under load a read may be momentarily unknown
            since = cell.mark("ur.pos_m")
            cell.command("ur", ref_pos_c=pose)
            await cell.wait("ur.pos_m", pose)
            assert await cell.robot_stands_at("ur", pose), f"ur reported {pose} before the robot got there"
            went = cell.trace("ur.pos_m", since)
            assert went in ([start, "unknown", pose], [start, pose]), f"ur {pose}: ur.pos_m went {went}"
            seen_between += went == [start, "unknown", pose]

        await step("mir", "mir.pos_m", "at_station", ["at_kitting", "moving", "at_station"], goto_c="station")
        # take the lift tool: coupled at its slot, it leaves the dock with the robot
        await move("dock_lift_tool")
        await step("rsp", "rsp.tool_m", "lift_tool", ["none", "lift_tool"], lock_c=True)
        assert cell.values["rsp.locked_m"] is True and cell.values["dock.lift_tool_home_m"] is True
        await move("home")
        await cell.wait("dock.lift_tool_home_m", False)
        await step("lift", "lift.pos_m", "up", ["down", "between", "up"], ref_c="up")
        await step("lift", "lift.pos_m", "down", ["up", "between", "down"], ref_c="down")
        # put it back: released at its slot, it is home
        await move("dock_lift_tool")
        await step("rsp", "rsp.tool_m", "none", ["lift_tool", "none"], lock_c=False)
        await cell.wait("dock.lift_tool_home_m", True)
        assert cell.values["rsp.locked_m"] is False
        # the operator in the shared zone, then with the nutrunner in hand in the robot zone
        await step("human", "cam.zone_m", "shared", ["outside", "shared"], instr_c="place_bolts")
        await step("human", "cam.zone_m", "outside", ["shared", "outside"], instr_c="none")
        await step("human", "cam.zone_m", "robot", ["outside", "robot"], instr_c="tighten_pipe1")
        await cell.wait("dock.nutrunner_home_m", False)
        await step("nr", "nr.tqr_m", True, [False, True], run_c=True)
        assert cell.values["nr.run_m"] is True and cell.values["nr.fail_m"] is False
        await step("nr", "nr.run_m", False, [True, False], run_c=False)
        assert cell.values["nr.tqr_m"] is False
        await step("human", "cam.zone_m", "outside", ["robot", "outside"], instr_c="none")
        await cell.wait("dock.nutrunner_home_m", True)
        # the nutrunner on the robot tightens a bolt
        await move("home")
        await move("dock_nutrunner")
        await step("rsp", "rsp.tool_m", "nutrunner", ["none", "nutrunner"], lock_c=True)
        await move("home")
        await cell.wait("dock.nutrunner_home_m", False)
        await move("above_engine")
        await move("at_bolt1")
        await step("nr", "nr.tqr_m", True, [False, True], run_c=True)
        await step("nr", "nr.run_m", False, [True, False], run_c=False)
        await move("at_bolt2")  # along the ring of bolts
        await step("mir", "mir.pos_m", "at_kitting", ["at_station", "moving", "at_kitting"], goto_c="kitting")
        # A driver that named the target as soon as it was commanded would never show the robot between
        # poses; a starved machine misses a short move's `unknown` now and then, not in every move.
        assert seen_between > 0, "ur.pos_m was never `unknown` between two poses"
        assert not cell.dead_hubs()
        # Every device still answers. Not at one instant: a driver that finds its simulator stalled (a
        # starved process) reports it unknown and reconnects, as it should; one that died never comes back.
        await cell.wait_all_measured(timeout=20.0)
    print(f"reference device story in sim mode: {time.monotonic() - began:.1f} s")


# --- whole stations ----------------------------------------------------------------------------

async def _run(config: Path, run_dir: Path, speed: float, time_limit: float) -> tuple[int, list[str]]:
    lines: list[str] = []
    options = Options(config=str(config), speed=speed, mode=DeviceMode.SIM, run_dir=run_dir, time_limit=time_limit)
    code = await run_station(options, say=lines.append)
    return code, lines


@pytest.mark.slow
async def test_small_station_runs_to_completion_in_sim_mode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    began = time.monotonic()
    code, lines = await _run(SMALL, tmp_path, speed=2.0, time_limit=180)
    output = "\n".join(lines)
    assert code == 0, output
    assert "finished: 18/18 operations" in output, output
    assert "emulated (no protocol simulator): agv (agv), human (operator)" in output
    print(f"small station in sim mode: {time.monotonic() - began:.1f} s\n{lines[-1] if lines else ''}")


@pytest.mark.slow
async def test_reference_station_runs_to_completion_in_sim_mode(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The demonstrator of hubs.toml, every device with a protocol simulator on its real driver."""
    monkeypatch.chdir(ROOT)
    began = time.monotonic()
    code, lines = await _run(REFERENCE, tmp_path, speed=1.0, time_limit=400)
    output = "\n".join(lines)
    assert code == 0, output
    assert f"finished: {len(ea.build_model().operations)}/45 operations" in output, output
    for device in ("Modbus coupler (rsp, dock)", "MiR REST API (mir)", "fake UR controller (ur)", "RFID reader (rfid)",
                   "camera tracker feed (cam)", "nr (nutrunner): simulated inside hub pi-tool",
                   "lift (lift): simulated inside hub pi-tool"):
        assert device in output, output
    print(f"reference station in sim mode: {time.monotonic() - began:.1f} s\n{lines[-1] if lines else ''}")
