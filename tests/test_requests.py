"""The console's requests at the controller (controller/requests.py), on a ControlCore without I/O.

A small station: the fault station's robot and nutrunner with two bolts, plus an operator
who places the bolts (confirming only once the frame is placed) and seats the frame.
The world is driven by hand: `settle` ticks and lets planning finish, `measure` plays a hub.
"""

from __future__ import annotations

import asyncio

import pytest

from common.bus.protocol import Request
from common.model import Domain, Model, OperationState, Value, estimated, operation, tracking
from common.resources import nutrunner, operator, ur
from common.wire.ctl import ConsoleReply, ConsoleRequest, RequestAnswered
from common.wire.messages import decode, encode
from controller.requests import Requests, coerce
from controller.stack import build_controller_stack

BOLTS = (1, 2)
FRAME = "engine.frame_e"


def build_model() -> Model:
    bolt_states = Domain.enum("absent", "placed", "tightened")
    poses = ("home", "at_bolt1", "at_bolt2")
    moves = (("home", "at_bolt1"), ("home", "at_bolt2"), ("at_bolt1", "at_bolt2"))
    human = operator("human", ("seat_frame", "place_bolts"),
                     confirm_when={"place_bolts": f"{FRAME} == placed"},
                     on_confirm={"seat_frame": f"{FRAME} := placed",
                                 "place_bolts": [f"engine.bolt{i}_e := placed" for i in BOLTS]})
    return Model(
        "request_station",
        (ur("ur", poses, moves, "home"), nutrunner("nr"), human),
        estimated=(estimated(FRAME, Domain.enum("on_kit", "placed"), "on_kit"),
                   *(estimated(f"engine.bolt{i}_e", bolt_states, "absent") for i in BOLTS)),
        tracking=tuple(tracking(f"engine.bolt{i}_tightened",
                                f"engine.bolt{i}_e == placed && nr.tqr_m && ur.pos_m == at_bolt{i}",
                                f"engine.bolt{i}_e := tightened") for i in BOLTS),
        operations=(
            operation("SeatFrame", f"{FRAME} == on_kit", f"{FRAME} == placed"),
            operation("PlaceBolts", "engine.bolt1_e == absent", "engine.bolt1_e == placed"),
            operation("TightenBolt1", "engine.bolt1_e == placed", "engine.bolt1_e == tightened"),
        ),
    )


class Rig:
    def __init__(self) -> None:
        model = build_model()
        stack = build_controller_stack(model)
        self.compiled = stack.compiled
        self.core = stack.control_core()
        self.persisted: list[list[str]] = []
        self.wakes = 0
        self.requests = Requests(self.core, persist=self.persisted.append, wake=self._wake)

    def _wake(self) -> None:
        self.wakes += 1

    def ask(self, action: str, **fields: object) -> ConsoleReply:
        return self.requests.apply(ConsoleRequest(action=action, origin="test", **fields))  # type: ignore[arg-type]  # each test passes its fields

    def value(self, path: str) -> Value:
        return self.core.state[self.compiled.index[path]]

    def op(self, name: str) -> str:
        return self.core.op_state(name)

    def settle(self, rounds: int = 3) -> None:
        for _ in range(rounds):
            self.core.tick()
            request = self.core.plan_request()
            if request is not None:
                self.core.adopt(request, self.core.solve(request))

    def measure(self, **values: Value) -> None:
        self.core.ingest({path.replace("__", "."): v for path, v in values.items()})
        self.settle()


@pytest.fixture
def rig() -> Rig:
    return Rig()


def test_start_requests_and_says_what_the_operation_waits_for(rig: Rig) -> None:
    reply = rig.ask("start", operation="TightenBolt1")
    assert reply.accepted and "engine.bolt1_e == placed" in reply.reason
    assert rig.persisted[-1] == ["TightenBolt1"] and rig.wakes == 1
    rig.settle()
    assert rig.op("TightenBolt1") == OperationState.INITIAL  # its precondition does not hold yet
    again = rig.ask("start", operation="TightenBolt1")
    assert not again.accepted and "already started" in again.reason
    (said,) = rig.core.events.log.recent(1)
    assert isinstance(said, RequestAnswered) and (said.request, said.accepted) == ("start TightenBolt1", False)
    assert said.text.startswith("console (test): start TightenBolt1 refused: ")


def test_start_of_an_unknown_operation_is_refused(rig: Rig) -> None:
    reply = rig.ask("start", operation="TightenBolt9")
    assert not reply.accepted and reply.reason == "no operation 'TightenBolt9' in model request_station"


def test_unknown_action_is_refused_with_the_known_ones(rig: Rig) -> None:
    reply = rig.ask("launch")
    assert not reply.accepted and "unknown action 'launch'" in reply.reason and "unforce" in reply.reason


def test_stop_returns_an_executing_operation_to_initial_and_drops_its_plan(rig: Rig) -> None:
    assert rig.ask("start", operation="SeatFrame").accepted
    rig.settle()
    assert rig.op("SeatFrame") == OperationState.EXECUTING
    assert rig.core.progress is not None and rig.value("human.instr_c") == "seat_frame"
    reply = rig.ask("stop", operation="SeatFrame")
    assert reply.accepted
    assert rig.op("SeatFrame") == OperationState.INITIAL and "SeatFrame" not in rig.core.requested
    assert rig.core.progress is None  # the plan made for its goal is gone
    assert rig.persisted[-1] == []
    rig.settle()
    assert rig.op("SeatFrame") == OperationState.INITIAL  # not started again
    assert not rig.ask("stop", operation="SeatFrame").accepted


def test_stop_cancels_a_start_still_waiting_for_its_precondition(rig: Rig) -> None:
    rig.ask("start", operation="TightenBolt1")
    reply = rig.ask("stop", operation="TightenBolt1")
    assert reply.accepted and reply.reason == "it no longer waits to start"
    assert rig.core.requested == []


def test_reset_only_from_finished_and_a_finished_operation_cannot_start(rig: Rig) -> None:
    rig.ask("start", operation="SeatFrame")
    rig.settle()
    assert not rig.ask("reset", operation="SeatFrame").accepted  # executing: stop it first
    rig.measure(human__done_m=True)  # the operator confirms on the watch
    assert rig.op("SeatFrame") == OperationState.FINISHED
    refused = rig.ask("start", operation="SeatFrame")
    assert not refused.accepted and "reset it" in refused.reason
    assert rig.ask("reset", operation="SeatFrame").accepted
    rig.settle()
    assert rig.op("SeatFrame") == OperationState.INITIAL  # and stays: no longer requested
    assert rig.value(FRAME) == "placed"  # what it recorded stays recorded
    assert rig.ask("reset", operation="SeatFrame").reason == "SeatFrame is already initial"


def test_pause_holds_deliberate_transitions_but_not_automatic_ones(rig: Rig) -> None:
    assert rig.ask("pause").accepted
    assert rig.ask("pause").reason == "already paused"
    reply = rig.ask("start", operation="SeatFrame")
    assert reply.accepted and "starts on resume" in reply.reason
    rig.settle()
    assert rig.op("SeatFrame") == OperationState.INITIAL  # an operation start is deliberate: held
    assert rig.ask("resume").accepted
    rig.settle()
    assert rig.op("SeatFrame") == OperationState.EXECUTING and rig.value("human.instr_c") == "seat_frame"
    rig.ask("pause")
    rig.measure(human__done_m=True)
    # Automatic: the instruction is withdrawn, the frame recorded and the operation finishes while paused.
    assert rig.value("human.instr_c") == "none" and rig.value(FRAME) == "placed"
    assert rig.op("SeatFrame") == OperationState.FINISHED
    rig.ask("start", operation="PlaceBolts")
    rig.measure(human__done_m=False)
    assert rig.value("human.instr_c") == "none"  # no new instruction while paused
    assert rig.ask("resume").accepted and not rig.core.paused
    rig.settle()
    assert rig.value("human.instr_c") == "place_bolts"


def test_confirm_holds_the_button_until_the_instruction_is_withdrawn(rig: Rig) -> None:
    assert rig.ask("confirm").reason == "human has no instruction to confirm"
    rig.ask("start", operation="SeatFrame")
    rig.settle()
    reply = rig.ask("confirm")
    assert reply.accepted and reply.reason == "human confirmed seat_frame"
    assert rig.core.forced_paths() == ["human.done_m"]
    rig.measure(human__done_m=False)  # the hub still reads the button released: the console's press wins
    assert rig.value("human.instr_c") == "none" and rig.value(FRAME) == "placed"
    assert rig.op("SeatFrame") == OperationState.FINISHED
    assert rig.core.forced_paths() == [] and rig.value("human.done_m") is False  # released: the hub's value


def test_confirm_is_refused_while_the_model_does_not_allow_it(rig: Rig) -> None:
    rig.core.load({"human.instr_c": "place_bolts"})  # instructed, but the frame is not seated
    reply = rig.ask("confirm", resource="human")
    assert not reply.accepted and reply.reason == "human cannot confirm place_bolts yet: engine.frame_e == placed"
    assert rig.core.forced_paths() == []
    assert not rig.ask("confirm", resource="ur").accepted


def test_confirm_is_refused_when_the_operator_already_confirmed(rig: Rig) -> None:
    rig.ask("start", operation="SeatFrame")
    rig.settle()
    rig.core.ingest({"human.done_m": True})  # the watch's press arrived, not yet acted upon
    assert rig.ask("confirm").reason == "human has already confirmed seat_frame"


def test_force_a_measured_variable_hides_the_hub_until_undone(rig: Rig) -> None:
    reply = rig.ask("force", path="nr.tqr_m", value=True)
    assert reply.accepted and "measurement is ignored" in reply.reason
    assert rig.value("nr.tqr_m") is True and rig.core.forced_paths() == ["nr.tqr_m"]
    rig.measure(nr__tqr_m=False, nr__run_m=True)
    assert rig.value("nr.tqr_m") is True and rig.value("nr.run_m") is True  # others still follow the hub
    reply = rig.ask("unforce", path="nr.tqr_m")
    assert reply.accepted and reply.reason == "nr.tqr_m is false again"  # the hub's newest value
    assert rig.ask("unforce", path="nr.tqr_m").reason == "nr.tqr_m is not forced"


def test_force_a_command_blocks_the_transitions_that_write_it(rig: Rig) -> None:
    rig.ask("start", operation="SeatFrame")
    assert rig.ask("force", path="human.instr_c", value="none").accepted
    rig.settle()
    # SeatFrame's plan instructs seat_frame: that step waits while the instruction is held at none.
    assert rig.op("SeatFrame") == OperationState.EXECUTING and rig.core.progress is not None
    assert rig.value("human.instr_c") == "none" and rig.core.events.replans == 0
    assert rig.ask("unforce", path="human.instr_c").reason == "human.instr_c is none again"
    rig.settle()
    assert rig.value("human.instr_c") == "seat_frame"


def test_force_an_estimate_and_its_own_value_is_what_undo_restores(rig: Rig) -> None:
    assert rig.ask("force", path=FRAME, value="placed").accepted
    assert rig.core.own_state()[rig.compiled.index[FRAME]] == "on_kit"  # what is persisted
    assert rig.ask("unforce", path=FRAME).accepted
    assert rig.value(FRAME) == "on_kit"


@pytest.mark.parametrize(("path", "value", "reason"), [
    ("nr.tqr", True, "no variable 'nr.tqr' in model request_station"),
    ("ur.pos_m", "at_bolt9", "'at_bolt9' is outside the domain of ur.pos_m ({home, at_bolt1, at_bolt2, unknown})"),
    ("nr.run_c", 3, "3 is outside the domain of nr.run_c (bool)"),
    ("op.SeatFrame", "finished", "op.SeatFrame is the state of an operation: start, stop or reset it instead"),
    ("nr.run_c", None, "force nr.run_c: no value given"),
])
def test_force_is_refused_with_the_reason(rig: Rig, path: str, value: Value | None, reason: str) -> None:
    reply = rig.ask("force", path=path, value=value)
    assert not reply.accepted and reply.reason == reason
    assert rig.core.forced_paths() == [] and rig.wakes == 0


def test_values_typed_as_text_are_read_in_the_model_notation() -> None:
    assert coerce("true") is True and coerce("false") is False and coerce("-2") == -2 and coerce("home") == "home"
    assert ConsoleRequest(action="force", path="nr.run_c", value=True).describe() == "force nr.run_c := true"


def test_answer_decodes_the_query_and_refuses_garbage(rig: Rig) -> None:
    async def ask(payload: bytes | None) -> ConsoleReply:
        return decode(await rig.requests.answer(Request("s/ctl/request", "", payload)), ConsoleReply)

    reply = asyncio.run(ask(encode(ConsoleRequest(action="pause"))))
    assert reply.accepted and rig.core.paused
    garbage = asyncio.run(ask(b"\x01\x02"))
    assert not garbage.accepted and garbage.reason.startswith("unreadable request: ")
    assert not asyncio.run(ask(None)).accepted
