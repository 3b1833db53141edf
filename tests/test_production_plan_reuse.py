"""A station running orders asks its planner the same questions every order (the product reset, the devices
home): the satisficing member's answer is remembered per question (controller/planner/reuse.py,
`SearchMemory`), so asking again costs no search and gives the same plan with the same counted work."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from common.model import Const, all_of
from common.model.compiled import CompiledModel
from controller.planner import Budget, Plan, Planner, validate_plan
from controller.planner import portfolio as portfolio_module
from controller.planner.reuse import SearchedAnswer, SearchMemory, question_key
from tests.stations import synthetic

FIRST_ONLY = Budget(improve_expansions=0)  # what virtual time asks: the satisficing member's answer


def counting_greedy(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []
    search = portfolio_module.greedy

    def counted(*args: Any, **kwargs: Any) -> object:
        calls.append(1)
        return search(*args, **kwargs)

    monkeypatch.setattr(portfolio_module, "greedy", counted)
    return calls


def test_a_question_asked_again_gets_the_same_plan_without_a_search(monkeypatch: pytest.MonkeyPatch) -> None:
    model = synthetic.build_model(12)
    compiled = CompiledModel(model)
    goals = {op.name: op.goal for op in model.operations}
    planner = Planner(compiled)
    start = compiled.initial()
    first = planner.plan(start, goals, budget=FIRST_ONLY)
    assert isinstance(first, Plan) and first.stats.method == "greedy"
    # The same goals from elsewhere: the plan memory now holds a plan that does not pass through `start`.
    (bolt,) = model.operations[-1].goal.paths()
    elsewhere = compiled.with_values(start, {bolt: "tightened"})
    other = planner.plan(elsewhere, goals, budget=FIRST_ONLY)
    assert isinstance(other, Plan) and start not in other.states
    searches = counting_greedy(monkeypatch)
    again = planner.plan(start, goals, budget=FIRST_ONLY)
    assert not searches, "asked again, the question was searched again"
    assert isinstance(again, Plan) and again.stats.method == "greedy"
    assert again.steps == first.steps and again.states == first.states
    assert (again.stats.expanded, again.stats.generated) == (first.stats.expanded, first.stats.generated)
    validate_plan(compiled, start, again, all_of(*goals.values()))
    # Another expansion count is another question: searched.
    planner.memory.clear()  # (else the plan just remembered passes through `start`: its rest, no search)
    planner.plan(start, goals, budget=Budget(first_expansions=19_999, improve_expansions=0))
    assert searches


def test_an_answer_the_clock_may_have_cut_short_is_not_remembered() -> None:
    model = synthetic.build_model(12)
    compiled = CompiledModel(model)
    goals = {op.name: op.goal for op in model.operations}
    counted_only = Planner(compiled)
    counted_only.plan(compiled.initial(), goals, budget=Budget(first_expansions=1, improve_expansions=0))
    assert len(counted_only.searches) == 1  # out of its count: the same count runs out the same way
    clocked = Planner(compiled)
    clocked.plan(compiled.initial(), goals, budget=Budget(first_expansions=1, improve_expansions=0, seconds=60.0))
    assert len(clocked.searches) == 0


def test_the_memory_keeps_the_newest_questions_only() -> None:
    memory = SearchMemory(kept=2)
    keys = [question_key((i,), Const(True), (), frozenset(), 10, (0, False)) for i in range(3)]
    answer: Callable[[int], SearchedAnswer] = lambda i: SearchedAnswer(((i, 0),), None, i, i)  # noqa: E731
    memory.remember(keys[0], answer(0))
    memory.remember(keys[1], answer(1))
    assert memory.recall(keys[0]) == answer(0)  # recalled: the newest now
    memory.remember(keys[2], answer(2))
    assert len(memory) == 2 and memory.recall(keys[1]) is None
    assert memory.recall(keys[0]) == answer(0) and memory.recall(keys[2]) == answer(2)


def test_a_race_learnt_in_time_makes_the_question_new(monkeypatch: pytest.MonkeyPatch) -> None:
    """A remembered answer may take the step a race learnt since forbids (controller/timed_check.py): the
    question is asked again, and while the learnt races are suspended it is yet another question."""
    model = synthetic.build_model(12)
    compiled = CompiledModel(model)
    goals = {op.name: op.goal for op in model.operations}
    planner = Planner(compiled)
    start = compiled.initial()
    calls = counting_greedy(monkeypatch)
    planner.plan(start, goals, budget=FIRST_ONLY)
    searched = len(calls)
    victim, due = compiled.transitions[0], compiled.transitions[1]
    assert planner.timed_races.forbid(victim, due)
    planner.memory.clear()  # as the loop forgets the refused plan (controller/loop.py)
    planner.plan(start, goals, budget=FIRST_ONLY)
    assert len(calls) > searched, "the answer remembered before the race was learnt was reused"
    searched = len(calls)
    planner.memory.clear()
    with planner.timed_races.suspended_while():
        planner.plan(start, goals, budget=FIRST_ONLY)
    assert len(calls) > searched
