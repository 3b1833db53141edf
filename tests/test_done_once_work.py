"""The physical work of a run counted from its recordings (deploy/local/done_once.py `WorkCount`): each
tracking ability's device conditions becoming true is a piece of work, at most once per order, also over a
controller restart."""

from __future__ import annotations

from common.model import Value
from common.stations import load_model
from common.wire.ctl import OrderStarted
from controller.recording.reader import Record
from controller.recording.schema import CommandRecord, RecordKind, StateRecord, TickRecord
from deploy.local.done_once import DoneOnce, WorkCount, work_asked, work_items

REFERENCE = "common.stations.engine_assembly:build_model"
MODEL = load_model(REFERENCE)
BOLT7 = "engine.bolt7_tightened"
AT_BOLT7: dict[str, Value] = {"rsp.tool_m": "nutrunner", "ur.pos_m": "at_bolt7"}


def _started(order: int, variant: str = "full", t: float = 0.0) -> Record:
    return Record(t, RecordKind.EVENT, "order_started", OrderStarted(order, f"E-{order}", variant, 1))


def _tick() -> Record:
    return Record(0.0, RecordKind.TICK, "", TickRecord())


def _torque(on: bool, t: float = 0.0) -> Record:
    """The nutrunner's state as a controller took it in at `t` (states taken in at one tick share their t)."""
    return Record(t, RecordKind.STATE, "nr", StateRecord(values={"nr.tqr_m": on}))


def _count() -> WorkCount:
    return WorkCount(MODEL, work_items(MODEL))


def test_each_tracking_ability_is_a_piece_of_work_and_a_variant_asks_for_its_own() -> None:
    items = {item.name: item for item in work_items(MODEL)}
    assert str(items[BOLT7].seen) == "nr.tqr_m && rsp.tool_m == nutrunner && ur.pos_m == at_bolt7"
    light = work_asked(MODEL, items.values(), MODEL.variant_by_name["light"].requested(MODEL.operations))
    full = work_asked(MODEL, items.values(), MODEL.variant_by_name["full"].requested(MODEL.operations))
    assert BOLT7 in light and "engine.bolt21_tightened" not in light and "engine.pipe1_tightened" not in light
    assert full - light == {*(f"engine.bolt{i}_tightened" for i in range(21, 25)), "engine.filter3_tightened",
                            "engine.pipe1_tightened", "engine.pipe2_tightened"}


def test_torque_twice_on_one_bolt_in_one_order_is_redone_work() -> None:
    work = _count()
    work.count([_tick(), _started(1), Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7)),
                _torque(True, 1.0), _torque(False, 2.0), _torque(True, 3.0)])
    assert work.redone() == {(1, BOLT7): 2}
    done = DoneOnce([], work=work)
    assert done.failed() and "REDONE" in done.text()


def test_the_same_bolt_in_the_next_order_is_new_work() -> None:
    work = _count()
    work.count([_tick(), _started(1), Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7)),
                _torque(True, 1.0), _torque(False, 2.0), _started(2, t=3.0), _torque(True, 4.0)])
    assert not work.redone() and work.seen[1, BOLT7] == work.seen[2, BOLT7] == 1
    assert (1, "engine.bolt1_tightened") in work.missed()


def test_a_restarted_controller_finding_the_torque_its_predecessor_saw_counts_nothing() -> None:
    work = _count()
    work.count([_tick(), _started(1), Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7)),
                _torque(True)])  # killed here
    # The next controller starts from the model's initial values and takes the hubs' states before its first tick.
    work.count([Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7)), _torque(True), _tick(),
                _torque(False)])
    assert work.seen == {(1, BOLT7): 1} and work.order == 1


def test_work_done_while_no_controller_recorded_is_counted_once_by_the_next() -> None:
    work = _count()
    work.count([_tick(), _started(1), Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7))])
    work.count([Record(0.0, RecordKind.STATE, "ur", StateRecord(values=AT_BOLT7)), _torque(True), _tick(),
                _torque(False), Record(0.0, RecordKind.COMMAND, "nr", CommandRecord(values={"nr.run_c": False},
                                                                                    seq=3))])
    assert work.seen == {(1, BOLT7): 1}


def test_the_states_of_one_tick_are_one_instant_whatever_their_order_in_the_recording() -> None:
    """A chaos run at speed 4: the nutrunner torqued in its dock (pipe 2 is tightened only out of it, in the
    operator's hand), and the next tick took in both the dock seeing it leave and the torque gone. Read record
    by record, the dock's state came first: a moment of torque outside the dock that never was, and the real
    tightening after it was counted as pipe 2 tightened twice."""
    pipe2 = "engine.pipe2_tightened"
    in_hand: dict[str, Value] = {"human.instr_c": "tighten_pipe2"}  # (the robot holds no nutrunner at start)
    work = _count()
    work.count([_tick(), _started(1),
                Record(0.5, RecordKind.STATE, "dock", StateRecord(values={"dock.nutrunner_home_m": True})),
                Record(0.6, RecordKind.COMMAND, "human", CommandRecord(values=in_hand, seq=1)),
                _torque(True, 1.0),  # in the dock
                Record(2.0, RecordKind.STATE, "dock", StateRecord(values={"dock.nutrunner_home_m": False})),
                _torque(False, 2.0),  # the same tick
                _torque(True, 3.0)])  # in the operator's hand
    assert work.seen == {(1, pipe2): 1}, work.seen
    # Taken in at two ticks, the same records are a moment of torque outside the dock: work.
    work = _count()
    work.count([_tick(), _started(1),
                Record(0.5, RecordKind.STATE, "dock", StateRecord(values={"dock.nutrunner_home_m": True})),
                Record(0.6, RecordKind.COMMAND, "human", CommandRecord(values=in_hand, seq=1)),
                _torque(True, 1.0),
                Record(2.0, RecordKind.STATE, "dock", StateRecord(values={"dock.nutrunner_home_m": False})),
                _torque(False, 2.1)])
    assert work.seen == {(1, pipe2): 1}, work.seen
