"""Cooperative stopping (controller/planner/stopping.py): a newer request ends the improvement at its next
look at the stop test, even inside A*'s table builds, and leaves no table half built, so the next search on
the same planner gives what a fresh planner gives. Promptness is counted in looks, never timed."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from common.model import Predicate, all_of
from common.model.compiled import CompiledModel, State
from common.stations import load_model
from controller.planner import Budget, NoPlan, Plan, Planner
from controller.planner.search import SearchEnd, astar
from controller.planner.steps import stable_goal
from controller.stack import build_controller_stack
from tests.stations import synthetic

MACHINE_TENDING = f"{Path(__file__).resolve().parent.parent / 'examples' / 'machine_tending' / 'model.py'}:build_model"


@dataclass
class Case:
    compiled: CompiledModel
    forbidden: Predicate | None
    start: State
    goals: Mapping[str, Predicate]

    def planner(self) -> Planner:
        planner = Planner(self.compiled, self.forbidden)
        planner.prepare()
        return planner


@pytest.fixture(scope="module")
def machine_tending() -> Case:
    """Its goal at start: a first plan at once, then A* builds its tables cold and shows it minimal."""
    model = load_model(MACHINE_TENDING)
    stack = build_controller_stack(model)
    compiled = stack.compiled
    state = compiled.unpack(compiled.initial())
    goals = {op.name: op.goal for op in model.operations if op.pre.eval(state)}
    return Case(compiled, stack.supervisor.forbidden, compiled.initial(), goals)


@dataclass
class StopAt:
    """The worker's stop test, scripted: armed once the first answer is out (as `NewerRequest`), then true
    from its `at`-th look on. Records every look and whether A*'s heuristic for the goals was stored then."""

    planner: Planner
    goals: tuple[Predicate, ...]
    start: State
    at: int | None = None
    armed: bool = False
    looks: int = 0
    looks_after_stop: int = 0
    ready: list[bool] = field(default_factory=list)

    def __call__(self) -> bool:
        if not self.armed:
            return False
        self.looks += 1
        self.ready.append(self.planner.heuristic_ready(self.goals, frozenset(), self.start))
        if self.at is not None and self.looks >= self.at:
            self.looks_after_stop += self.looks > self.at
            return True
        return False


def run(planner: Planner, case: Case, stop: StopAt | None) -> list[Plan | NoPlan]:
    budget = Budget(improve_expansions=1_000_000, symbolic_layers=1_000, stop=stop)
    answers = []
    for answer in planner.plan_anytime(case.start, case.goals, budget=budget):
        answers.append(answer)
        if stop is not None:
            stop.armed = True
    return answers


def test_a_stop_anywhere_in_the_improvement_ends_it_at_once_and_the_next_search_is_the_fresh_one(
        machine_tending: Case) -> None:
    case = machine_tending
    goals = tuple(case.goals.values())
    reference_planner = case.planner()
    whole = StopAt(reference_planner, goals, case.start)
    reference = run(reference_planner, case, whole)
    best = reference[-1]
    assert isinstance(best, Plan) and best.stats.minimal and len(reference) >= 1
    building = whole.ready.count(False)  # looks while A*'s tables for the start were being built
    assert building > 5 and whole.looks > 100, (building, whole.looks)
    # Stop points all through the improvement: the heuristic's build, its tables for the start (where a stop
    # used to leave half-built tables), A*'s search.
    points = sorted({*range(1, building + 1, max(1, building // 20)), building, building + 1,
                     *range(building + 1, whole.looks + 1, max(1, whole.looks // 10))})
    for at in points:
        planner = case.planner()
        stop = StopAt(planner, goals, case.start, at)
        stopped = run(planner, case, stop)
        assert stop.looks == at and stop.looks_after_stop == 0, f"stop at look {at}: {stop.looks} looks"
        assert isinstance(stopped[0], Plan) and not stopped[-1].stats.minimal, (at, stopped)
        # Tables cut short are not ready (a warm A* in a first answer would build them); finished ones are.
        assert planner.heuristic_ready(goals, frozenset(), case.start) == (at > building), at
        again = run(planner, case, None)[-1]
        assert isinstance(again, Plan) and again.stats.minimal, (at, again)
        assert [s.transition for s in again.steps] == [s.transition for s in best.steps], at


def test_a_table_build_stopped_part_way_is_not_stored(machine_tending: Case) -> None:
    """Without cooperative checks in the builders, the build ran to its end before A* looked."""
    case = machine_tending
    goals = tuple(case.goals.values())
    planner = case.planner()
    stop = StopAt(planner, goals, case.start, at=3)
    run(planner, case, stop)
    assert stop.ready[:3] == [False, False, False]
    assert not planner.heuristic_ready(goals, frozenset(), case.start)


def test_searches_say_how_they_ended() -> None:
    model = synthetic.build_model(8)
    compiled = CompiledModel(model)
    planner = Planner(compiled)
    goal = all_of(*(op.goal for op in model.operations))
    is_goal = stable_goal(compiled, compiled.predicate(goal), frozenset())
    heuristic = planner.heuristic((goal,))
    system = planner.step_system(frozenset())
    found = astar(system, compiled.initial(), is_goal, None, heuristic, None)
    assert found.end is SearchEnd.FOUND and found.moves
    leftovers: list[object] = []
    stopped = astar(system, compiled.initial(), is_goal, None, heuristic, None, stop=lambda: True,
                    leftovers=leftovers)
    assert stopped.end is SearchEnd.STOPPED and stopped.timed_out and stopped.moves is None
    assert len(leftovers) == 1  # its open list and closed states, for the caller to free later
    counted = astar(system, compiled.initial(), is_goal, None, heuristic, None, max_expansions=2)
    assert counted.end is SearchEnd.OUT_OF_BUDGET and counted.timed_out
    bounded = astar(system, compiled.initial(), is_goal, None, heuristic, None, bound=len(found.moves))
    assert bounded.end is SearchEnd.EXHAUSTED and not bounded.timed_out
