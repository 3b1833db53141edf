"""A compiled model, a start state and goals as a planning task with the planner's step semantics.

One action per step the planner may take (`controller/planner/steps.py`, `bfs.micro_steps`):

* each automatic ability transition: its guard, and no automatic transition before it in model
  order enabled (the engine fires the first enabled one);
* each deliberate transition: its guard with the supervisor's synthesized part, no automatic
  transition enabled (`stable`: automatics are urgent), and no race (`RaceCheck`: the command
  would start an effect that an effect already due could overtake, or be overtaken by);
* each outcome of each effect: its guard, and `stable`.

Every action also needs the current state not forbidden (`allowed`): a forbidden state is a
dead end, so no plan passes through one; the goal is the goals, `stable` and `allowed` (the
engine looks at goals only once the automatics have fired). Plan length = number of actions =
the number of steps `hubctl plan` counts.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from common.model import Predicate, TransitionKind
from common.model.actions import Assign
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.predicates import FALSE, Not, Ref, all_of, any_of
from controller.planner.steps import Move, RaceCheck

from .formulas import ALWAYS, NEVER, Fact, Facts, Formula, Named, Unexpressible, regress
from .formulas import all_of as formula_all_of

Condition = Formula  # a formula, named or not


@dataclass(frozen=True)
class Effect:
    """Under `when` (true if empty, read in the state before), the facts made true and those made false."""

    when: tuple[Fact, ...]
    adds: tuple[Fact, ...]
    deletes: tuple[Fact, ...]


@dataclass(frozen=True)
class Action:
    name: str
    move: Move  # (CompiledTransition.number, outcome): what the action is in statehub's plans
    precondition: tuple[Condition, ...]  # a conjunction
    effects: tuple[Effect, ...]


class Names:
    """PDDL identifiers (letters, digits, `-`, `_`; case-insensitive), unique across one task."""

    RESERVED = frozenset({"and", "or", "not", "when", "imply", "exists", "forall", "either", "define", "domain",
                          "problem", "object", "number", "at", "over", "start", "end", "all", "increase",
                          "decrease", "assign", "total-cost", "preference", "always", "sometime", "within"})

    def __init__(self) -> None:
        self.taken: set[str] = set(self.RESERVED)

    def make(self, text: str) -> str:
        base = re.sub(r"[^a-z0-9_-]+", "-", text.lower()).strip("-") or "x"
        if not base[0].isalpha():
            base = f"x{base}"
        name, count = base, 1
        while name in self.taken:
            count += 1
            name = f"{base}-{count}"
        self.taken.add(name)
        return name


@dataclass
class Task:
    """The planning task: facts, actions, the start and the goal, with the names the files use."""

    name: str
    facts: dict[Fact, str]  # every (variable, value) fact and its predicate name
    actions: tuple[Action, ...]
    init: tuple[Fact, ...]
    goal: tuple[Condition, ...]  # a conjunction
    names: Names = field(default_factory=Names)
    # The conditions every step needs, as named in the actions: not forbidden, and per automatic transition (in
    # model order) its guard false; `stable` is the conjunction of `idle`. A flavour without derived predicates
    # checks them with steps of its own (`flat.py`).
    allowed: Condition = ALWAYS
    idle: tuple[Named, ...] = ()
    stable: Condition = ALWAYS

    @property
    def moves(self) -> dict[str, Move]:
        return {a.name: a.move for a in self.actions}


def _effects(facts: Facts, actions: tuple[Assign, ...], where: str) -> tuple[Effect, ...]:
    result: list[Effect] = []
    plain_adds: list[Fact] = []
    plain_deletes: list[Fact] = []
    for action in actions:
        values = facts.values(action.path, where)
        if isinstance(action.value, Ref):
            source = facts.values(action.value.path, where)
            missing = [v for v in source if v not in values]
            if missing:
                raise Unexpressible(f"{where}: the copy {action} can write {missing[0]!r}, outside the domain of "
                                    f"{action.path}")
            for v in source:
                result.append(Effect((Fact(action.value.path, v),), (Fact(action.path, v),),
                                     tuple(Fact(action.path, w) for w in values if w != v)))
            continue
        if facts.is_value(action.path, action.value, where) == NEVER:
            raise Unexpressible(f"{where}: {action} writes a value outside the domain of {action.path}")
        plain_adds.append(Fact(action.path, action.value))
        plain_deletes += [Fact(action.path, w) for w in values if Fact(action.path, w) != plain_adds[-1]]
    if plain_adds:
        result.insert(0, Effect((), tuple(plain_adds), tuple(plain_deletes)))
    return tuple(result)


def race_predicate(compiled: CompiledModel, race: RaceCheck, t: CompiledTransition) -> Predicate:
    """When deliberate `t` races an effect (`steps.races_after`), as a predicate over the state before `t`.

    Each guard is regressed through `t` first: most become constant there (the effects `t` cannot start,
    the rivals it disables), and their pairs drop out."""
    command = t.source.outcomes[0]
    after_t: dict[int, Predicate] = {}

    def guard_after(x: CompiledTransition) -> Predicate:
        if x.number not in after_t:
            after_t[x.number] = regress(compiled.guard_of(x.source), command)
        return after_t[x.number]

    cases: list[Predicate] = []
    for f, rivals in race.watched(t):
        if guard_after(f) == FALSE:
            continue
        for e in rivals:
            if guard_after(e) == FALSE:
                continue
            overtakes = any_of(
                *(Not(regress(regress(compiled.guard_of(e.source), o), command)) for o in f.source.outcomes),
                *(Not(regress(regress(compiled.guard_of(f.source), o), command)) for o in e.source.outcomes))
            cases.append(all_of(guard_after(f), guard_after(e), overtakes))
    return any_of(*cases)


def encode(compiled: CompiledModel, start: State, goal: Predicate, forbidden: Predicate | None = None,
           disabled: frozenset[str] = frozenset(), name: str = "") -> Task:
    """The task of reaching `goal` from `start` with the model's ability transitions, leaving out those that
    touch a `disabled` resource as the planner does (raises Unexpressible)."""
    facts = Facts(compiled)
    names = Names()
    fact_names = {Fact(path, v): names.make(f"{path}-{v}") for path, values in facts.domains.items() for v in values}
    for path, value in zip(compiled.paths, start, strict=True):
        if facts.is_value(path, value, "the start state") == NEVER:
            raise Unexpressible(f"the start state: {path} = {value!r} is outside its domain")
    allowed: Condition = ALWAYS
    if forbidden is not None:
        allowed = Named(names.make("allowed"), facts.formula(forbidden, "the forbidden states", positive=False))
    idle: list[Named] = []  # per automatic transition: its guard does not hold
    actions: list[Action] = []
    automatic = [t for t in compiled.automatic if not (t.resources & disabled)]
    for t in automatic:
        if len(t.source.outcomes) != 1:
            raise Unexpressible(f"automatic transition {t.name} has {len(t.source.outcomes)} alternative outcomes: "
                                f"only effects may have several")
        where = f"automatic transition {t.name}"
        guard = compiled.guard_of(t.source)
        actions.append(Action(names.make(f"auto-{t.name}"), (t.number, 0),
                              (allowed, facts.formula(guard, where), *idle),
                              _effects(facts, t.source.outcomes[0], where)))
        idle.append(Named(names.make(f"idle-{t.name}"), facts.formula(guard, where, positive=False)))
    stable: Condition = Named(names.make("stable"), formula_all_of(list(idle))) if idle else ALWAYS
    race = RaceCheck(compiled, disabled)
    # Model order, as the planner's ties go; operation transitions (stage 1) are never planned.
    controlled = {t.number for t in (*compiled.deliberate, *compiled.effects) if not (t.resources & disabled)}
    for t in compiled.transitions:
        if t.number not in controlled:
            continue
        where = f"{t.kind.value} transition {t.name}"
        enabled = facts.formula(compiled.guard_of(t.source), where)
        checks: list[Condition] = [allowed, stable, enabled]
        if t.kind is TransitionKind.DELIBERATE and race.watched(t):
            checks.append(Named(names.make(f"no-race-{t.name}"),
                                facts.formula(race_predicate(compiled, race, t), where, positive=False)))
        several = len(t.source.outcomes) > 1
        for o, outcome in enumerate(t.source.outcomes):
            label = f"{'effect' if t.kind is TransitionKind.EFFECT else 'do'}-{t.name}" + (f"-or{o}" if several else "")
            actions.append(Action(names.make(label), (t.number, o), tuple(checks), _effects(facts, outcome, where)))
    init = tuple(Fact(path, value) for path, value in zip(compiled.paths, start, strict=True))
    task_goal = (allowed, stable, facts.formula(goal, "the goal"))
    return Task(names.make(name or compiled.model.name), fact_names, tuple(actions), init, task_goal, names,
                allowed, tuple(idle), stable)


def goal_of(goals: Mapping[str, Predicate]) -> Predicate:
    return all_of(*goals.values())
