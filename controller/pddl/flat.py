"""The task without derived predicates, disjunctions or conditional effects: plain STRIPS with negative
preconditions and action costs, which every Fast Downward heuristic accepts (lm-cut, merge-and-shrink and
pattern databases refuse axioms and conditional effects; disjunctions written in place blow up in the
translator).

The conditions every step needs (not forbidden, and each automatic transition's guard false: `allowed`,
`idle-…`, `stable`) become facts `ok-…`. A zero-cost *check* step makes one true when the state satisfies
it (a check per disjunct of the condition's disjunctive normal form), and every step that writes a
variable the condition reads makes it false again, so `ok-c` holds only while `c` does. The checks of
these urgent conditions go in model order (a check needs the earlier ones done), so after a step the
search meets one order of checks, not every interleaving. Other disjunctive conditions (a race check, a
disjunctive guard, the clauses of a synthesized guard) become copies of the step, one per disjunct, while
their product stays small; the rest are checked in a chain of the action's own (`intend-T`, a check per
clause, T), with nothing else allowed in between. A copy `x := y` is one copy of the step per value of `y`.

Steps cost 1 and checks 0, so the optimal cost is the length statehub counts; a plan read back drops the
checks and names each copy by the action it copies.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field

from controller.planner.steps import Move

from .encoding import Action, Condition, Task
from .formulas import AllOf, AnyOf, Fact, Named, Other, Unexpressible

COPIES = 64  # most copies of one action for its disjunctive conditions; beyond, a condition gets checks
TERMS = 4096  # most disjuncts of one condition's normal form


@dataclass(frozen=True)
class Flag:
    """A fact of the flat task that is no variable's value: a condition checked (`ok-…`), the goal reached."""

    name: str


Atom = Fact | Flag


@dataclass(frozen=True)
class Literal:
    atom: Atom
    positive: bool


Term = frozenset[Literal]  # a conjunction


@dataclass(frozen=True)
class Step:
    name: str
    origin: str | None  # the task's action this step is (a copy of); None: a check, cost 0
    precondition: Term
    adds: tuple[Atom, ...]
    deletes: tuple[Atom, ...]


@dataclass
class FlatTask:
    name: str
    facts: dict[Fact, str]
    flags: list[Flag]
    steps: list[Step]
    init: tuple[Fact, ...]
    goal: Flag
    moves: dict[str, Move] = field(default_factory=dict)  # the task's action names and their moves

    def origins(self, plan: Iterable[str]) -> tuple[str, ...]:
        """A plan's steps as the task's action names, checks left out."""
        by_name = {s.name: s.origin for s in self.steps}
        result = []
        for name in plan:
            if name not in by_name:
                raise ValueError(f"the plan names step {name!r}, not a step of the flat task")
            origin = by_name[name]
            if origin is not None:
                result.append(origin)
        return tuple(result)


class TooLarge(Exception):
    pass


def consistent(term: Iterable[Literal]) -> Term | None:
    """The conjunction simplified (`x = a` makes `x != b` redundant), or None when it cannot hold."""
    positive: dict[str, Fact] = {}
    items = set(term)
    for literal in items:
        atom = literal.atom
        if literal.positive and isinstance(atom, Fact) and positive.setdefault(atom.path, atom) != atom:
            return None
    kept = []
    for literal in items:
        if Literal(literal.atom, not literal.positive) in items:
            return None
        atom = literal.atom
        if not literal.positive and isinstance(atom, Fact) and atom.path in positive:
            if positive[atom.path] == atom:
                return None
            continue
        kept.append(literal)
    return frozenset(kept)


def conjoin(left: list[Term], right: list[Term], cap: int) -> list[Term]:
    result: dict[Term, None] = {}
    for a, b in itertools.product(left, right):
        term = consistent(a | b)
        if term is not None:
            result[term] = None
            if len(result) > cap:
                raise TooLarge
    return list(result)


def normal_form(formula: Condition, cap: int = TERMS) -> list[Term]:
    """The formula as a disjunction of conjunctions of literals (raises TooLarge beyond `cap` disjuncts)."""
    if isinstance(formula, Fact):
        return [frozenset({Literal(formula, True)})]
    if isinstance(formula, Other):
        return [frozenset({Literal(formula.fact, False)})]
    if isinstance(formula, Named):
        return normal_form(formula.formula, cap)
    if isinstance(formula, AllOf):
        terms: list[Term] = [frozenset()]
        for item in formula.items:
            terms = conjoin(terms, normal_form(item, cap), cap)
        return terms
    assert isinstance(formula, AnyOf)
    union: dict[Term, None] = {}
    for item in formula.items:
        union.update(dict.fromkeys(normal_form(item, cap)))
        if len(union) > cap:
            raise TooLarge
    return list(union)


def parts(condition: Condition) -> list[Condition]:
    """The conjuncts of a condition, through names."""
    if isinstance(condition, Named):
        return parts(condition.formula)
    if isinstance(condition, AllOf):
        return [p for item in condition.items for p in parts(item)]
    return [condition]


def reads(terms: list[Term]) -> frozenset[str]:
    return frozenset(lit.atom.path for term in terms for lit in term if isinstance(lit.atom, Fact))


@dataclass
class Check:
    flag: Flag
    terms: list[Term]
    reads: frozenset[str]
    after: frozenset[Literal]  # what a check of it needs first: the earlier urgent checks


@dataclass
class Need:
    """What a condition asks of a step: literals, checked flags, and disjunctions left to expand into copies."""

    literals: set[Literal] = field(default_factory=set)
    flags: list[Flag] = field(default_factory=list)
    choices: list[list[Term]] = field(default_factory=list)

    def add(self, other: Need) -> None:
        self.literals |= other.literals
        self.flags += [f for f in other.flags if f not in self.flags]
        self.choices += other.choices


class Flattener:
    def __init__(self, task: Task, copies: int = COPIES) -> None:
        self.task = task
        self.copies = copies
        self.checks: list[Check] = []
        # Keyed by identity: the actions hold these very objects, and hashing a station's formulas is slow.
        self.urgent: dict[int, Need] = {}  # allowed and each idle condition
        self.needs: dict[int, Need] = {}
        done: set[Literal] = set()
        for condition in (task.allowed, *task.idle):
            need = Need()
            for part in parts(condition):
                terms = self.terms_of(part)
                if len(terms) == 1:
                    need.literals |= terms[0]
                    continue
                flag = Flag(task.names.make(f"ok-{self.label(condition)}"))
                self.checks.append(Check(flag, terms, reads(terms), frozenset(done)))
                done.add(Literal(flag, True))
                need.flags.append(flag)
            self.urgent[id(condition)] = need
        self.stable = Need()
        for condition in task.idle:
            self.stable.add(self.urgent[id(condition)])
        self.urgent[id(task.stable)] = self.stable
        self.busy = Flag(task.names.make("busy"))
        self.chain_flags: list[Flag] = []

    def label(self, condition: Condition) -> str:
        return condition.name if isinstance(condition, Named) else "condition"

    def terms_of(self, formula: Condition) -> list[Term]:
        try:
            return normal_form(formula)
        except TooLarge:
            raise Unexpressible(f"a condition of more than {TERMS} disjuncts ({self.label(formula)}) has no flat "
                                f"form") from None

    def need(self, condition: Condition) -> Need:
        if id(condition) in self.urgent:
            return self.urgent[id(condition)]
        if id(condition) not in self.needs:
            need = Need()
            for part in parts(condition):
                terms = self.terms_of(part)
                if len(terms) == 1:
                    need.literals |= terms[0]
                else:
                    need.choices.append(terms)
            self.needs[id(condition)] = need
        return self.needs[id(condition)]

    def steps_of(self, action: Action) -> list[Step]:
        need = Need()  # a fresh one: `add` must not change the cached needs
        for condition in action.precondition:
            need.add(self.need(condition))
        base = frozenset(need.literals | {Literal(f, True) for f in need.flags})
        # Disjunctions expand into copies while they stay few (the smallest first); the rest are checked in a
        # chain of the action's own, one clause after the other.
        expanded: list[list[Term]] = []
        chained: list[list[Term]] = []
        size = 1
        for terms in sorted(need.choices, key=len):
            terms = [t for t in terms if consistent(t | base) is not None]
            if not terms:
                return []  # the action's conditions contradict each other: it never applies
            if any(consistent(t | base) == consistent(base) for t in terms):
                continue  # implied by the rest of the precondition
            if size * len(terms) <= self.copies:
                expanded.append(terms)
                size *= len(terms)
            else:
                chained.append(terms)
        steps: list[Step] = []
        if chained:
            # `intend` starts the chain from a state where the action's other conditions hold; while the chain runs
            # (`busy`) no other chain starts, and nothing else can happen (the state is stable: no automatic
            # transition may fire, and every other step needs its own chain or is a check already done).
            progress = [Flag(self.task.names.make(f"{action.name}-{k}")) for k in range(len(chained) + 1)]
            steps.append(Step(self.task.names.make(f"intend-{action.name}"), None,
                              base | {Literal(self.busy, False)}, (self.busy, progress[0]), ()))
            for k, terms in enumerate(chained):
                for number, term in enumerate(terms):
                    steps.append(Step(self.task.names.make(f"check-{progress[k + 1].name}-{number}"), None,
                                      term | {Literal(progress[k], True)}, (progress[k + 1],), (progress[k],)))
            self.chain_flags += progress
            base = base | {Literal(progress[-1], True)}
        else:
            base = base | {Literal(self.busy, False)}  # no step between another action's chain and its end
        # Conditional effects (copies x := y) read one variable each: a copy of the step per value.
        whens = sorted({f for e in action.effects for f in e.when}, key=repr)
        by_variable: dict[str, list[Term]] = {}
        for fact in whens:
            by_variable.setdefault(fact.path, []).append(frozenset({Literal(fact, True)}))
        terms = [base]
        for choice in (*expanded, *by_variable.values()):
            terms = conjoin(terms, choice, cap=10**6)
        for term in terms:
            holding = {lit.atom for lit in term if lit.positive}
            applied = [e for e in action.effects if all(f in holding for f in e.when)]
            adds: tuple[Atom, ...] = tuple(dict.fromkeys(f for e in applied for f in e.adds))
            deletes: list[Atom] = [f for e in applied for f in e.deletes if f not in adds]
            written = {f.path for f in (*adds, *deletes) if isinstance(f, Fact)}
            deletes += [c.flag for c in self.checks if c.reads & written]
            if chained:
                deletes += [self.busy, progress[-1]]
            name = action.name if len(terms) == 1 else self.task.names.make(f"{action.name}-v")
            steps.append(Step(name, action.name, term, adds, tuple(dict.fromkeys(deletes))))
        return steps

    def flatten(self) -> FlatTask:
        steps = [s for action in self.task.actions for s in self.steps_of(action)]
        for check in self.checks:
            for number, term in enumerate(check.terms):
                steps.append(Step(self.task.names.make(f"check-{check.flag.name}-{number}"), None,
                                  frozenset(term | check.after), (check.flag,), ()))
        goal = Flag(self.task.names.make("goal-reached"))
        need = Need()
        for condition in self.task.goal:
            need.add(self.need(condition))
        base = frozenset(need.literals | {Literal(f, True) for f in need.flags})
        terms = [base]
        for choice in need.choices:
            terms = conjoin(terms, choice, cap=10**6)
        steps += [Step(self.task.names.make("reach-goal"), None, term, (goal,), ()) for term in terms]
        flags = [c.flag for c in self.checks] + [self.busy, *self.chain_flags, goal]
        return FlatTask(self.task.name, self.task.facts, flags, steps, self.task.init, goal, self.task.moves)


def flatten(task: Task, copies: int = COPIES) -> FlatTask:
    """The flat task; `copies` bounds the copies of one action for its disjunctive conditions (1: every
    disjunctive condition is checked in the action's chain)."""
    return Flattener(task, copies).flatten()


def render_flat(task: FlatTask) -> tuple[str, str]:
    """(domain.pddl text, problem.pddl text): STRIPS with negative preconditions and action costs."""

    def atom(a: Atom) -> str:
        return f"({task.facts[a]})" if isinstance(a, Fact) else f"({a.name})"

    def literal(lit: Literal) -> str:
        return atom(lit.atom) if lit.positive else f"(not {atom(lit.atom)})"

    actions = []
    for step in task.steps:
        pre = " ".join(sorted(literal(lit) for lit in step.precondition))
        effects = [atom(a) for a in step.adds] + [f"(not {atom(a)})" for a in step.deletes]
        if step.origin is not None:
            effects.append("(increase (total-cost) 1)")
        actions.append(f"  (:action {step.name}\n    :parameters ()\n    :precondition (and {pre})\n"
                       f"    :effect (and {' '.join(effects)}))")
    predicates = [f"({n})" for n in task.facts.values()] + [f"({f.name})" for f in task.flags]
    domain = "\n".join([f"(define (domain {task.name})",
                        "  (:requirements :strips :negative-preconditions :action-costs)",
                        "  (:predicates " + "\n    ".join(predicates) + ")",
                        "  (:functions (total-cost) - number)", *actions]) + ")\n"
    init = "\n    ".join([atom(f) for f in task.init] + ["(= (total-cost) 0)"])
    problem = (f"(define (problem {task.name}-problem)\n  (:domain {task.name})\n  (:init\n    {init})\n"
               f"  (:goal {atom(task.goal)})\n  (:metric minimize (total-cost)))\n")
    return domain, problem
