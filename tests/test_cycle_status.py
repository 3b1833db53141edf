"""The predicted finish and the lower bound in the controller's status (issue 21, item 4): the status's optional
`cycle` (common/wire/ctl.py), what the console's plan line shows of it, and the cycle report `hubctl up` over
processes prints at the end from the last status, the same lines the in-process run prints."""

from __future__ import annotations

import msgspec

from common.model import OperationState
from common.wire.ctl import CycleInfo, PlanInfo, StatusMessage
from common.wire.messages import Message, decode, encode
from controller.console.view import plan_summary
from controller.cycle import Bound, CycleRecord, Waited, WaitKind
from controller.engine import TickResult
from controller.loopmeter import LoopMeter
from controller.recording.hooks import VirtualClock
from controller.stack import build_controller_stack
from controller.statuspublisher import StatusPublisher, cycle_info
from controller.watchdog import Watchdog
from deploy.local.station import cycle_lines
from tests.timing_stations.feeder import build_model


def a_cycle() -> CycleRecord:
    """Two resources: r worked from 0 to 2 s and waited 1 s for g; g worked from 1 to 1.5 s."""
    record = CycleRecord(["r", "g"])
    record.planned(0.0, 4.0, Bound(3.0, 3.0, "r", 2.0))
    record.dispatched(0.0, ["r"], Waited(WaitKind.RESOURCE, "g"))
    record.measured(2.0, ["r"])
    record.dispatched(1.0, ["g"], Waited(WaitKind.RESOURCE, "r"))
    record.measured(1.5, ["g"])
    record.effect_done("r", 2.0)
    record.dispatched(3.0, ["r"], Waited(WaitKind.RESOURCE, "g"))
    return record


def test_the_end_report_over_processes_says_what_the_in_process_run_says() -> None:
    report = a_cycle().report(5.0)
    assert len(report.lines()) == 3 and "waited for" in report.lines()[1]
    info = decode(encode(StatusMessage(station="s", controller="c", time=0.0, uptime=0.0,
                                       cycle=cycle_info(report))), StatusMessage).cycle
    assert cycle_lines(info) == report.lines()
    assert cycle_lines(None) == []


def test_a_status_without_cycle_decodes_and_an_older_reader_skips_it() -> None:
    status = StatusMessage(station="s", controller="c", time=0.0, uptime=0.0, cycle=cycle_info(a_cycle().report(5.0)))
    older = msgspec.msgpack.encode({k: v for k, v in msgspec.structs.asdict(status).items() if k != "cycle"})
    assert decode(older, StatusMessage).cycle is None

    class OlderStatus(Message, kw_only=True):  # what a console that knows no `cycle` reads
        station: str
        uptime: float

    assert decode(encode(status), OlderStatus) == OlderStatus(station="s", uptime=0.0)


def test_the_status_carries_the_cycle_ended_when_every_operation_finished() -> None:
    model = build_model()
    stack = build_controller_stack(model)
    clock = VirtualClock()
    core = stack.control_core(clock)
    record = a_cycle()
    publisher = StatusPublisher("s", "c", core, Watchdog({}), {}, LoopMeter(), cycle=record)
    clock.now = 5.0
    cycle = publisher.status().cycle
    # The bound is r's work: the first plan's chain (3 s) bounds that plan's executions, not the run.
    assert cycle is not None and (cycle.cycle_s, cycle.predicted_s, cycle.bound_s) == (5.0, 4.0, 2.0)
    assert [r.resource for r in cycle.idle] == ["r", "g"] and cycle.idle[0].waits[0][0] == "resource g"
    # Every operation finished at 6 s: the cycle stays 6 s in the statuses after.
    core.request("Place")
    core.load({model.operation_by_name["Place"].state_path: OperationState.FINISHED.value})
    assert core.all_finished()
    clock.now = 6.0
    publisher.ticked(TickResult(core.state, finished=["Place"]))
    clock.now = 9.0
    cycle = publisher.status().cycle
    assert cycle is not None and cycle.cycle_s == 6.0
    assert StatusPublisher("s", "c", core, Watchdog({}), {}, LoopMeter()).status().cycle is None


def test_the_consoles_plan_line_shows_the_predicted_finish_and_the_bound() -> None:
    plan = PlanInfo(id=1, goals=["Place"], steps=10, done=b"")
    cycle = CycleInfo(cycle_s=2.0, predicted_s=7.25, bound_s=6.5)
    assert plan_summary(plan, cycle).endswith("ends ~7.2 s, bound 6.5 s")
    assert "bound" not in plan_summary(plan)
