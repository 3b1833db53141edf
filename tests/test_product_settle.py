"""An order ends when the devices have let go of its product (controller/production/settle.py)."""

from __future__ import annotations

from common.model.compiled import CompiledModel
from common.stations import load_model
from controller.production.settle import SETTLE_MIN_S, ProductSettle

REFERENCE = "common.stations.engine_assembly:build_model"


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_order_waits_while_the_operator_is_still_to_confirm_a_task_on_the_product() -> None:
    """Seen over processes: the product reset while the operator was still told to tighten pipe 2; pipe 2 back to
    `absent`, the confirmation could never come, the instruction stood for ever and the next order stalled."""
    compiled = CompiledModel(load_model(REFERENCE))
    clock = Clock()
    settle = ProductSettle(compiled, {"human.tighten_pipe2.executing.effect": 0.5}, clock)
    told = compiled.with_values(compiled.initial(), {"human.instr_c": "tighten_pipe2", "human.done_m": False,
                                                     "engine.pipe2_e": "tightened"})
    assert settle.in_hand(told)
    clock.now = 1.9
    assert settle.in_hand(told)  # within the bound: four times the confirmation's 0.5 s, at least 2 s
    confirmed = compiled.with_values(told, {"human.instr_c": "none", "human.done_m": True})
    assert not settle.in_hand(confirmed)  # the button's release reads no product: it may come on the next engine
    assert not settle.in_hand(compiled.initial())


def test_a_device_that_never_lets_go_holds_the_order_only_for_a_bounded_time() -> None:
    compiled = CompiledModel(load_model(REFERENCE))
    clock = Clock()
    settle = ProductSettle(compiled, {}, clock)
    told = compiled.with_values(compiled.initial(), {"human.instr_c": "tighten_pipe2", "engine.pipe2_e": "tightened"})
    assert settle.in_hand(told)
    clock.now = SETTLE_MIN_S + 0.1
    assert not settle.in_hand(told)
