"""Plans executed as a partial order (controller/deorder.py) and their cycle bound (controller/cycle.py)."""

from __future__ import annotations

import itertools

from common.model import Model, Phase, Resource, ability, command, forbid, measured, operation
from common.model.compiled import CompiledModel
from controller.cycle import lower_bound, predicted_finish, step_seconds
from controller.deorder import Execution, order
from controller.stack import build_controller_stack
from tests.test_engine import plan_for, two_lamps


def lamps_and_guarded_lamp() -> Model:
    """Two lamps; a specification forbids lamp b switched on while lamp a is lit and a third lamp c switched
    on: c is never switched on here, so b's synthesized guard (which reads a's lamp) always holds and must
    not make b wait for a."""
    resources = []
    for name in ("a", "b", "c"):
        on_c, on_m = command(f"{name}.on_c", initial=False), measured(f"{name}.on_m")
        switch = ability(f"{name}.switch", enabled=Phase(~on_c & ~on_m, deliberate=f"{name}.on_c := true"),
                         executing=Phase(on_c & ~on_m, effects=f"{name}.on_m := true"))
        resources.append(Resource(name, (on_c, on_m), (switch,)))
    spec = forbid("not_b_with_a_and_c", "b.on_c && a.on_m && c.on_c")
    return Model("guarded", tuple(resources), specifications=(spec,),
                 operations=(operation("AB", "!a.on_m && !b.on_m", "a.on_m && b.on_m"),))


def test_independent_resources_run_in_parallel() -> None:
    c = CompiledModel(two_lamps())
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    ordering = order(c, plan)
    commands = [j for j, s in enumerate(plan.steps) if s.transition.endswith("enabled")]
    assert all(not ordering.depends[j] for j in commands)


def test_a_satisfied_synthesized_guard_does_not_serialize() -> None:
    stack = build_controller_stack(lamps_and_guarded_lamp())
    c = stack.compiled
    assert "b.switch.enabled" in c.extra_guards  # the supervisor guards b's command by c's
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    names = [s.transition for s in plan.steps]
    b_on, a_lit = names.index("b.switch.enabled"), names.index("a.switch.executing.effect")
    assert a_lit in order(c, plan, Execution.TRACE).depends[b_on]  # the former rule: b waited for a's lamp
    assert not order(c, plan).depends[b_on]


def test_a_causal_link_is_kept() -> None:
    c = CompiledModel(two_lamps())
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    ordering = order(c, plan)
    names = [s.transition for s in plan.steps]
    effect = names.index("a.switch.executing.effect")
    assert names.index("a.switch.enabled") in ordering.producers[effect]


def test_the_trace_rule_stays_selectable() -> None:
    c = CompiledModel(two_lamps())
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    assert order(c, plan, Execution.TRACE).depends == order(c, plan, Execution.TRACE).trace


def test_bound_below_every_schedule_and_the_prediction_above_the_best() -> None:
    """Enumerate every order of the plan's effects, each started as soon as its order and its producers allow:
    the best of them is no faster than the bound and no slower than the predicted finish."""
    c = CompiledModel(two_lamps())
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    ordering = order(c, plan)
    for seconds in ({"a.switch.executing.effect": 1.0, "b.switch.executing.effect": 2.5},
                    {"a.switch.executing.effect": 3.0, "b.switch.executing.effect": 0.5}):
        durations = step_seconds(c, plan, seconds)
        bound = lower_bound(c, plan, ordering, durations).seconds
        best = min(_makespan(ordering.producers, durations, sequence)
                   for sequence in itertools.permutations(range(len(durations)))
                   if all(all(sequence.index(d) < sequence.index(j) for d in ordering.producers[j])
                          for j in sequence))
        assert bound <= best <= predicted_finish(ordering, durations)
        assert best == max(seconds.values())


def _makespan(producers: tuple[frozenset[int], ...], durations: list[float], sequence: tuple[int, ...]) -> float:
    finish: dict[int, float] = {}
    for j in sequence:
        finish[j] = max((finish[d] for d in producers[j]), default=0.0) + durations[j]
    return max(finish.values(), default=0.0)


def test_the_operator_mounts_the_filters_while_the_robot_tightens_the_bolts() -> None:
    from common.stations import load_model
    from deploy.local.inprocess import run_in_process

    lines: list[str] = []
    summary = run_in_process(load_model(), seed=1, report=lines.append, execution=Execution.PARTIAL_ORDER)
    assert summary.finished
    done = {line.split()[2]: float(line.split()[0].rstrip("s")) for line in lines if " done " in line}
    assert done["MountFilter3"] < done["TightenBolt24"]
    assert summary.cycle is not None and summary.cycle.bound > 0
