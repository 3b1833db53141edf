"""A task relaxed onto some of its variables: an optimal planner's length there is a lower bound on the task's.

Every condition of a task (`encoding.py`) is a formula without negation over (variable, value) facts, and its
derived conditions occur only positively. Replacing each fact of a dropped variable by "true" therefore makes
every precondition, derived condition and the goal weaker, and leaving out what actions write to dropped variables
changes nothing the kept conditions read. So every plan of the task, its steps on dropped variables taken out,
is a plan of the projection, and no longer: an optimal planner's length on the projection is at most the task's
optimum. When it equals the length of a plan valid in the whole task, that plan is shortest.

Why: an optimal planner may take hours on a whole station and seconds on the few variables a goal set is about
(the reference station's 24 bolts: SymK's symbolic search had not finished after ten minutes on the whole task,
and shows 241 steps in 30 s on the variables statehub's plan writes). The other variables still count through
the conditions they leave, weakened; a projection that leaves too much out only gives a weaker bound, never a
wrong one.

A copy `x := y` of a kept `x` keeps `y` too: which value it writes depends on it.
"""

from __future__ import annotations

from collections.abc import Iterable

from common.model import Predicate
from common.model.compiled import CompiledModel
from common.model.predicates import Ref
from controller.planner.plans import Plan

from .encoding import Action, Condition, Effect, Task
from .formulas import ALWAYS, AllOf, AnyOf, Fact, Named, Other, all_of, any_of


def copy_closure(compiled: CompiledModel, paths: Iterable[str]) -> frozenset[str]:
    """`paths` and every variable a transition copies into one of them, until none is missing."""
    copies: dict[str, set[str]] = {}
    for t in compiled.transitions:
        for outcome in t.source.outcomes:
            for assign in outcome:
                if isinstance(assign.value, Ref):
                    copies.setdefault(assign.path, set()).add(assign.value.path)
    kept = set(paths)
    frontier = list(kept)
    while frontier:
        for source in copies.get(frontier.pop(), ()):
            if source not in kept:
                kept.add(source)
                frontier.append(source)
    return frozenset(kept)


def plan_variables(compiled: CompiledModel, plan: Plan, goal: Predicate) -> frozenset[str]:
    """The variables a plan writes and the goal reads (with what copies into them): where a projection keeps
    the work of reaching the goal."""
    written = {path for step in plan.steps for path in compiled.by_name[step.transition].source.written()}
    return copy_closure(compiled, written | goal.paths())


class _Relaxed:
    """Formulas with the facts of dropped variables made true; a formula shared by many actions (`stable`,
    `allowed`) is relaxed once."""

    def __init__(self, kept: frozenset[str]) -> None:
        self.kept = kept
        self.done: dict[int, tuple[Condition, Condition]] = {}  # id -> (the formula, kept alive; its relaxation)

    def __call__(self, formula: Condition) -> Condition:
        known = self.done.get(id(formula))
        if known is not None:
            return known[1]
        relaxed: Condition
        if isinstance(formula, Fact):
            relaxed = formula if formula.path in self.kept else ALWAYS
        elif isinstance(formula, Other):
            relaxed = formula if formula.fact.path in self.kept else ALWAYS
        elif isinstance(formula, AllOf | AnyOf):
            items = [self(item) for item in formula.items]
            unchanged = all(new is old for new, old in zip(items, formula.items, strict=True))
            relaxed = formula if unchanged else (all_of if isinstance(formula, AllOf) else any_of)(items)
        else:
            inner = self(formula.formula)
            relaxed = (formula if inner is formula.formula else
                       ALWAYS if inner == ALWAYS else Named(formula.name, inner))
        self.done[id(formula)] = (formula, relaxed)
        return relaxed


def project(task: Task, compiled: CompiledModel, keep: Iterable[str]) -> Task:
    """The task relaxed onto the variables `keep` (with what copies into them): see the module docstring."""
    kept = copy_closure(compiled, keep)
    relax = _Relaxed(kept)
    actions: list[Action] = []
    for action in task.actions:
        effects: list[Effect] = []
        for effect in action.effects:
            adds = tuple(f for f in effect.adds if f.path in kept)
            if not adds:
                continue
            # The closure keeps what a kept variable's copy reads: an effect's condition is never dropped.
            assert all(f.path in kept for f in effect.when), f"{action.name}: a copy from a dropped variable"
            effects.append(Effect(effect.when, adds, tuple(f for f in effect.deletes if f.path in kept)))
        # A step that changes only dropped variables is never in a shortest plan of the projection.
        if effects or not action.effects:
            actions.append(Action(action.name, action.move, tuple(relax(c) for c in action.precondition),
                                  tuple(effects)))
    idle = tuple(relaxed for relaxed in map(relax, task.idle) if isinstance(relaxed, Named))
    return Task(task.name, {f: name for f, name in task.facts.items() if f.path in kept}, tuple(actions),
                tuple(f for f in task.init if f.path in kept), tuple(relax(c) for c in task.goal), task.names,
                relax(task.allowed), idle, relax(task.stable))
