"""Safety on every path (controller/safety.py, controller/command_hold.py), on the reference station's control core
without I/O, and on the controller service with hubs over the in-memory bus.

* A console force into a state a specification forbids is refused (naming it) and changes nothing; with
  the override it is applied and logged at WARNING with who asked.
* A forbidden state on the measured values stops every deliberate transition (operation starts, plan
  steps, planning), is reported once, and again when it clears; then the controller plans afresh.
* A forced command goes out under a fresh seq, which its hub mirrors.
* A restarted controller sends nothing to a resource whose mirror is late, and then takes its command
  state from the mirror (the real-process version is tests/test_held_restart.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from common.model import Kind, Value
from common.stations.engine_assembly import DOCK_POSES, HOME, build_model
from common.wire.ctl import (
    ConsoleReply,
    ConsoleRequest,
    ForbiddenState,
    ForbiddenStateCleared,
    HoldReleased,
    MirrorsMissing,
    ReplanReason,
    StatusMessage,
)
from common.wire.messages import decode, encode
from controller.control import ControlCore
from controller.requests import Requests
from controller.service import ControllerService
from controller.stack import ControllerStack, build_controller_stack
from tests.test_memory_station import FAULT_STATION, MemoryStation, Running

TOOL_RELEASED = "tool_released_outside_its_slot"
NUTRUNNER_RUNS = "robot_moves_while_its_nutrunner_runs"


@pytest.fixture(scope="module")
def reference() -> ControllerStack:
    return build_controller_stack(build_model())


@pytest.fixture
def core(reference: ControllerStack) -> ControlCore:
    return reference.control_core()


def commands(core: ControlCore) -> dict[str, Value]:
    """What the controller sends: every command variable's value."""
    return {p: core.state[core.compiled.index[p]] for p in core.model.paths_of_kind(Kind.COMMAND)}


def force(core: ControlCore, path: str, value: Value, *, override: bool = False) -> ConsoleReply:
    request = ConsoleRequest(action="force", path=path, value=value, origin="ann@decs", override=override)
    return Requests(core).apply(request)


def holding_a_tool_away_from_the_dock(core: ControlCore) -> None:
    core.load({"rsp.lock_c": True})
    core.ingest({"rsp.locked_m": True, "rsp.tool_m": "nutrunner", "ur.pos_m": HOME})
    assert DOCK_POSES["nutrunner"] != HOME
    core.tick()


def test_a_force_that_would_release_a_tool_away_from_its_slot_is_refused_and_changes_nothing(
        core: ControlCore, caplog: pytest.LogCaptureFixture) -> None:
    holding_a_tool_away_from_the_dock(core)
    before = commands(core)
    reply = force(core, "rsp.lock_c", False)
    assert not reply.accepted
    assert TOOL_RELEASED in reply.reason and "rsp.tool_m = nutrunner" in reply.reason, reply.reason
    assert "override" in reply.reason
    assert commands(core) == before and core.forced_paths() == []
    core.tick()
    assert commands(core) == before

    with caplog.at_level(logging.WARNING, logger="statehub.controller"):
        reply = force(core, "rsp.lock_c", False, override=True)
    assert reply.accepted, reply.reason
    assert commands(core) == {**before, "rsp.lock_c": False} and core.forced_paths() == ["rsp.lock_c"]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "override" in r.getMessage()]
    assert len(warnings) == 1
    assert "ann@decs" in warnings[0] and "force rsp.lock_c := false (override)" in warnings[0], warnings
    assert TOOL_RELEASED in warnings[0]
    # Now the state is forbidden: the controller reports it and stops.
    core.tick()
    assert [e.specification for e in core.events.log if isinstance(e, ForbiddenState)] == [TOOL_RELEASED]


def test_a_force_that_forbids_nothing_is_applied(core: ControlCore) -> None:
    holding_a_tool_away_from_the_dock(core)
    reply = force(core, "ur.ref_pos_c", DOCK_POSES["nutrunner"])
    assert reply.accepted, reply.reason
    assert commands(core)["ur.ref_pos_c"] == DOCK_POSES["nutrunner"]


def deliberate_fired(core: ControlCore, fired: list[str]) -> list[str]:
    deliberate = {t.name for t in core.compiled.deliberate} | {f"{op.state_path}.start" for op in core.model.operations}
    return [name for name in fired if name in deliberate]


def plan(core: ControlCore) -> None:
    request = core.plan_request()
    assert request is not None
    core.adopt(request, core.solve(request))


def test_a_forbidden_state_on_measured_values_stops_deliberate_transitions_and_is_reported_once(
        core: ControlCore) -> None:
    core.request(*(op.name for op in core.model.operations))
    assert core.tick().started, "the first operations start from the initial state"
    plan(core)
    assert core.progress is not None and core.progress.next_step() is not None
    running: dict[str, Value] = {"nr.run_m": True, "rsp.tool_m": "nutrunner", "ur.pos_m": "unknown"}
    core.ingest(running)
    for _ in range(3):
        result = core.tick()
        assert deliberate_fired(core, result.fired) == [], result.fired
        assert core.plan_request() is None
    # The changer holds the nutrunner unlocked (its command is still the initial false) away from its slot too.
    events = [e for e in core.events.log if isinstance(e, ForbiddenState | ForbiddenStateCleared)]
    assert events == [ForbiddenState(TOOL_RELEASED, {"rsp.lock_c": False, "rsp.tool_m": "nutrunner",
                                                     "ur.pos_m": "unknown"}),
                      ForbiddenState(NUTRUNNER_RUNS, running)]
    assert all(e.fault for e in events)

    core.ingest({"nr.run_m": False, "rsp.tool_m": "none", "ur.pos_m": HOME})
    core.tick()
    assert core.events.log.recent(2) == [ForbiddenStateCleared(TOOL_RELEASED), ForbiddenStateCleared(NUTRUNNER_RUNS)]
    assert core.need_plan_reason is not None and core.need_plan_reason.reason is ReplanReason.SAFE_AGAIN
    plan(core)
    assert deliberate_fired(core, core.tick().fired), "deliberate transitions go on once it cleared"


# --- the service, its hubs on the in-memory bus (the fault station: a robot and a nutrunner) ------------

def _dropped(key: str, payload: bytes, *, block: bool = False) -> None:
    """A publish that sends nothing."""


@pytest.fixture
async def station(tmp_path: Path) -> AsyncIterator[MemoryStation]:
    station = MemoryStation(FAULT_STATION, tmp_path / "controller.sqlite", hold=True)
    try:
        await station.start()
        await station.wait_for(station.all_healthy, "every resource healthy")
        yield station
    finally:
        await station.close()


def commands_from(station: MemoryStation, resource: str, controller: str) -> list[tuple[dict[str, Value], int]]:
    codec = station.codecs[resource]
    found: list[tuple[dict[str, Value], int]] = []
    for sample in station.commands:
        if station.keys.resource_of(sample.key) == resource:
            command = codec.decode_command(sample.payload)
            if command.controller == controller:
                found.append((codec.values(command), command.seq))
    return found


async def test_a_forced_command_goes_out_under_a_fresh_seq_that_its_hub_mirrors(station: MemoryStation) -> None:
    await station.wait_for(lambda: "ur" in station.last_commands(), "ur commanded")
    _, seq_before, controller = station.last_commands()["ur"]
    assert station.watcher is not None
    request = ConsoleRequest(action="force", path="ur.ref_pos_c", value="at_bolt1", origin="test")
    (reply,) = await station.watcher.get(station.keys.ctl("request"), payload=encode(request))
    assert decode(reply.payload, ConsoleReply).accepted
    await station.wait_for(lambda: station.last_commands()["ur"][0] == {"ref_pos_c": "at_bolt1"}, "the force sent")
    sent = [seq for values, seq in commands_from(station, "ur", str(controller)) if values["ref_pos_c"] == "at_bolt1"]
    assert min(sent) == seq_before + 1 and set(sent) == {seq_before + 1}
    # The hub applied it, and the watchdog sees that: no mirror lag.
    await station.wait_for(lambda: (status := station.status()) is not None and next(
        h for h in status.health if h.resource == "ur").mirror_lag == 0
        and station.all_healthy(), "ur mirrors the forced command")


async def test_a_restarted_controller_sends_nothing_to_a_resource_without_mirror_until_it_arrives(
        station: MemoryStation) -> None:
    assert station.watcher is not None
    request = ConsoleRequest(action="force", path="ur.ref_pos_c", value="at_bolt1", origin="test")
    await station.watcher.get(station.keys.ctl("request"), payload=encode(request))
    await station.wait_for(lambda: station.status() is not None and station.all_healthy()
                           and station.last_commands()["ur"][0] == {"ref_pos_c": "at_bolt1"}, "the robot commanded")
    first = station.current_status().controller
    await station.stop("controller")
    # The robot's hub runs on, but its states do not reach anyone (a network partition).
    hub_bus = station.running["ur10"].bus
    hub_bus.publish = _dropped  # type: ignore[method-assign]  # a partition: the instance's publish sends nothing
    bus = await type(hub_bus)(station.network).open()
    service = ControllerService(station.config, station.model, bus, db=str(station.db), mirror_wait_s=0.3,
                                planner_process=False)
    stop = asyncio.Event()
    station.running["controller"] = Running(bus, stop, asyncio.create_task(service.run(stop)))

    def status_of(controller: str) -> StatusMessage | None:
        return next((s for s in reversed(station.statuses) if s.controller == controller), None)

    await station.wait_for(lambda: status_of(service.controller_id) is not None, "the new controller's status")
    await station.wait_for(lambda: bool(commands_from(station, "nr", service.controller_id)), "nr commanded")
    for _ in range(10):  # a while of ticks and re-sends at 10 Hz
        await asyncio.sleep(0.1)
    assert commands_from(station, "ur", service.controller_id) == []
    latest = status_of(service.controller_id)
    assert latest is not None
    events = latest.events
    assert MirrorsMissing({"ur10": ["ur"]}) in events
    assert service.command_hold.held == {"ur"}

    with contextlib.suppress(AttributeError):
        del hub_bus.publish  # its states flow again
    await station.wait_for(lambda: bool(commands_from(station, "ur", service.controller_id)), "ur commanded again")
    assert {values["ref_pos_c"] for values, _ in commands_from(station, "ur", service.controller_id)} == {"at_bolt1"}
    assert service.command_hold.held == frozenset()
    await station.wait_for(lambda: (status := status_of(service.controller_id)) is not None
                           and HoldReleased("ur", "its mirror") in status.events, "the release reported")
    assert first != service.controller_id
