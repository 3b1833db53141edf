"""A model compiled for speed: states are tuples, guards and actions are generated Python functions.

The engine and the planner share this one execution semantics:

* a *step* fires one transition (one outcome of an effect);
* automatic transitions are urgent: after any step, the first enabled automatic
  transition (in model order) fires, until none is enabled (`close`).

`automatic`, `deliberate` and `effects` hold the *ability* transitions (stage 2,
what plans are made of). Operation transitions (stage 1: start and finish of
planning operations) are kept apart in `operation_transitions`: the engine runs
them, the planner never plans with them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from .model import Model
from .predicates import And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref, all_of
from .transitions import Transition, TransitionKind
from .variables import Value

State = tuple[Value, ...]
MAX_AUTOMATIC_STEPS = 10_000


class AutomaticCycle(RuntimeError):
    """Automatic transitions keep firing: the model has a cycle of automatic transitions."""


def predicate_source(predicate: Predicate, index: Mapping[str, int]) -> str:
    """A Python expression over the state tuple `s` equivalent to the predicate."""

    def operand(value: object) -> str:
        return f"s[{index[value.path]}]" if isinstance(value, Ref) else repr(value)

    def emit(p: Predicate) -> str:
        if isinstance(p, Const):
            return repr(p.value)
        if isinstance(p, IsTrue):
            return f"(s[{index[p.path]}] is True)"
        if isinstance(p, Eq):
            return f"(s[{index[p.path]}] == {operand(p.value)})"
        if isinstance(p, Ne):
            return f"(s[{index[p.path]}] != {operand(p.value)})"
        if isinstance(p, In):
            return f"(s[{index[p.path]}] in {tuple(p.values)!r})"
        if isinstance(p, Not):
            return f"(not {emit(p.operand)})"
        if isinstance(p, And):
            return "(" + " and ".join(emit(i) for i in p.items) + ")"
        if isinstance(p, Or):
            return "(" + " or ".join(emit(i) for i in p.items) + ")"
        raise TypeError(f"unknown predicate node {p!r}")

    return emit(predicate)


def compile_predicate(predicate: Predicate, index: Mapping[str, int]) -> Callable[[Sequence[Value]], bool]:
    # Any sequence: the generated expression only indexes the state (the timeline keeps it in a list).
    return eval(f"lambda s: {predicate_source(predicate, index)}")


def compile_assignments(
    assignments: Iterable[tuple[str, object]], index: Mapping[str, int]
) -> Callable[[State], State]:
    """A function returning the state after simultaneous assignment (right sides read the state before)."""
    parts = []
    for path, value in assignments:
        rhs = f"s[{index[value.path]}]" if isinstance(value, Ref) else repr(value)
        parts.append(f"l[{index[path]}] = {rhs}")
    body = "; ".join(parts) if parts else "pass"
    namespace: dict[str, object] = {}
    exec(f"def apply(s):\n    l = list(s); {body}\n    return tuple(l)", namespace)
    return namespace["apply"]  # type: ignore[return-value]  # exec defines it: no static type


class GuardSet(dict[str, Predicate]):
    """Extra guards by transition name, and which specifications each comes from (for explanations:
    a person reads "held back by spec X", not kilobytes of synthesized predicate)."""

    def __init__(self, guards: Mapping[str, Predicate] | None = None,
                 specs: Mapping[str, tuple[str, ...]] | None = None) -> None:
        super().__init__(guards or {})
        self.specs: dict[str, tuple[str, ...]] = dict(specs or {})


@dataclass(eq=False)
class CompiledTransition:
    number: int
    source: Transition
    guard: Callable[[State], bool]
    outcomes: tuple[Callable[[State], State], ...]
    reads: frozenset[int]
    writes: frozenset[int]
    resources: frozenset[str]

    @property
    def name(self) -> str:
        return self.source.name

    @property
    def kind(self) -> TransitionKind:
        return self.source.kind


class CompiledModel:
    """A model plus optional extra guards (synthesized from specifications), compiled."""

    def __init__(self, model: Model, extra_guards: Mapping[str, Predicate] | None = None) -> None:
        self.model = model
        self.paths: tuple[str, ...] = tuple(model.variables)
        self.index: dict[str, int] = {p: i for i, p in enumerate(self.paths)}
        self.domains = tuple(model.variables[p].domain for p in self.paths)
        self.extra_guards = dict(extra_guards or {})
        self.guard_specs: dict[str, tuple[str, ...]] = (
            dict(extra_guards.specs) if isinstance(extra_guards, GuardSet) else {})
        self.transitions: tuple[CompiledTransition, ...] = tuple(
            self._compile(n, t) for n, t in enumerate(model.transitions)
        )
        self.by_name = {t.name: t for t in self.transitions}
        operation_names = {t.name for t in model.operation_transitions}
        self.operation_transitions = tuple(t for t in self.transitions if t.name in operation_names)
        abilities = tuple(t for t in self.transitions if t.name not in operation_names)
        self.automatic = tuple(t for t in abilities if t.kind is TransitionKind.AUTOMATIC)
        self.deliberate = tuple(t for t in abilities if t.kind is TransitionKind.DELIBERATE)
        self.effects = tuple(t for t in abilities if t.kind is TransitionKind.EFFECT)

    def guard_of(self, transition: Transition) -> Predicate:
        """The full guard: the model's plus the synthesized one, if any."""
        extra = self.extra_guards.get(transition.name)
        return transition.guard if extra is None else all_of(transition.guard, extra)

    def _compile(self, number: int, t: Transition) -> CompiledTransition:
        guard = self.guard_of(t)
        reads = {self.index[p] for p in guard.paths()}
        for outcome in t.outcomes:
            for action in outcome:
                if isinstance(action.value, Ref):
                    reads.add(self.index[action.value.path])
        paths = guard.paths() | t.written()
        return CompiledTransition(
            number=number,
            source=t,
            guard=compile_predicate(guard, self.index),
            outcomes=tuple(compile_assignments(((a.path, a.value) for a in o), self.index) for o in t.outcomes),
            reads=frozenset(reads),
            writes=frozenset(self.index[p] for p in t.written()),
            resources=frozenset(p.split(".", 1)[0] for p in paths),
        )

    # --- states ---------------------------------------------------------------------
    def pack(self, state: Mapping[str, Value]) -> State:
        return tuple(state[p] for p in self.paths)

    def unpack(self, state: State) -> dict[str, Value]:
        return dict(zip(self.paths, state, strict=True))

    def initial(self) -> State:
        return self.pack(self.model.initial_state())

    def with_values(self, state: State, values: Mapping[str, Value]) -> State:
        as_list = list(state)
        for path, value in values.items():
            as_list[self.index[path]] = value
        return tuple(as_list)

    def predicate(self, predicate: Predicate) -> Callable[[Sequence[Value]], bool]:
        return compile_predicate(predicate, self.index)

    # --- semantics ------------------------------------------------------------------
    def close(
        self, state: State, disabled: Callable[[CompiledTransition], bool] | None = None
    ) -> tuple[State, list[CompiledTransition]]:
        """Fire enabled automatic ability transitions, first in model order each time, until none is enabled."""
        fired: list[CompiledTransition] = []
        automatic = self.automatic
        while True:
            for t in automatic:
                if t.guard(state) and (disabled is None or not disabled(t)):
                    state = t.outcomes[0](state)
                    fired.append(t)
                    break
            else:
                return state, fired
            if len(fired) > MAX_AUTOMATIC_STEPS:
                names = ", ".join(dict.fromkeys(t.name for t in fired[-20:]))
                raise AutomaticCycle(f"automatic transitions keep firing: {names}")

    def describe(self, state: State, paths: Iterable[str] | None = None) -> str:
        chosen = self.paths if paths is None else tuple(paths)
        return ", ".join(f"{p}={state[self.index[p]]}" for p in chosen)
