"""The model side of a model-based test: what one resource's effect transitions allow and expect.

A state of the test is a tuple over `ResourceOracle.paths`: the resource's measured
variables, then its command variables, then the *context*: every other variable the
resource's transitions read (other resources' variables, estimated variables), at
their last known values. The measured part is what the hub reports; the rest (the
*environment*) is what the hub applied (its mirror) and what the other hubs report.

An effect outcome may show up on the wire over several samples (a device's inputs
are not read atomically): `explain` lets an outcome's assignments appear one by one
and returns what is still *in flight*, which must appear within the deadline.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

from common.model import Model, Ref, Transition, TransitionKind, Value
from common.model.compiled import compile_predicate
from common.model.predicates import format_value

State = tuple[Value, ...]
Change = tuple[int, Value]  # (index into the state, the value it takes)

REACHABILITY_LIMIT = 200_000  # states or guard environments beyond which reachability is not decided


@dataclass(frozen=True)
class Effect:
    """An effect transition that writes the tested resource's measured variables."""

    transition: Transition
    guard: Callable[[State], bool]
    # per outcome: (measured index, constant value or index of the variable it copies)
    outcomes: tuple[tuple[tuple[int, Value | Ref], ...], ...]
    env_reads: tuple[int, ...]  # indices of commands and context the guard and outcomes read

    @property
    def name(self) -> str:
        return self.transition.name

    @property
    def phase(self) -> str:
        """`nr.tighten.resetting` for the effect of that phase (the name without `.effect`)."""
        return self.name.removesuffix(".effect")

    def describe_guard(self) -> str:
        return f"{self.phase}: {self.transition.guard}"


@dataclass(frozen=True)
class InFlight:
    """An effect outcome seen in part: the assignments that have not shown up yet."""

    effect: str
    outcome: int
    remaining: frozenset[Change]


class ResourceOracle:
    """The effects of `resource` in `model`, and what they allow between two observed states."""

    def __init__(self, model: Model, resource: str, *, max_effect_steps: int = 3) -> None:
        if resource not in model.resource_by_name:
            raise KeyError(f"model {model.name!r} has no resource {resource!r} "
                           f"(its resources: {', '.join(sorted(model.resource_by_name))})")
        if max_effect_steps < 1:
            raise ValueError(f"max_effect_steps must be 1 or more, got {max_effect_steps}")
        self.model = model
        self.resource = model.resource_by_name[resource]
        self.max_effect_steps = max_effect_steps
        self.measured: tuple[str, ...] = tuple(v.path for v in self.resource.measured)
        self.commands: tuple[str, ...] = tuple(v.path for v in self.resource.commands)
        own = set(self.measured)
        effect_transitions = [t for t in model.ability_transitions
                              if t.kind is TransitionKind.EFFECT and t.written() & own]
        self.controls: tuple[Transition, ...] = tuple(
            t for a in self.resource.abilities for t in a.transitions
            if t.kind in (TransitionKind.DELIBERATE, TransitionKind.AUTOMATIC) and t.written() & set(self.commands))
        read: set[str] = set()
        for t in (*effect_transitions, *self.controls):
            read |= t.read()
        self.context: tuple[str, ...] = tuple(sorted(read - own - set(self.commands)))
        self.paths: tuple[str, ...] = self.measured + self.commands + self.context
        self.index: dict[str, int] = {p: i for i, p in enumerate(self.paths)}
        self.n_measured = len(self.measured)
        initial = model.initial_state()
        self.initial_env: State = tuple(initial[p] for p in self.commands + self.context)
        self.initial_measured: State = tuple(initial[p] for p in self.measured)
        self.effects: tuple[Effect, ...] = tuple(self._effect(t) for t in effect_transitions)
        self.effect_by_name = {e.name: e for e in self.effects}
        self._control_guards = tuple(compile_predicate(t.guard, self.index) for t in self.controls)

    def _effect(self, t: Transition) -> Effect:
        outcomes = []
        env_reads = {self.index[p] for p in t.guard.paths()}
        for outcome in t.outcomes:
            assigns: list[tuple[int, Value | Ref]] = []
            for action in outcome:
                if action.path not in self.index or self.index[action.path] >= self.n_measured:
                    continue  # writes another resource: not observed on this resource's key
                if isinstance(action.value, Ref):
                    env_reads.add(self.index[action.value.path])
                assigns.append((self.index[action.path], action.value))
            outcomes.append(tuple(assigns))
        return Effect(t, compile_predicate(t.guard, self.index), tuple(outcomes),
                      tuple(sorted(i for i in env_reads if i >= self.n_measured)))

    # --- states -----------------------------------------------------------------------------
    def env_of(self, commands: Mapping[str, Value], context: Mapping[str, Value]) -> State:
        """The environment tuple: command values (by path), then context values (initial when unknown)."""
        values = dict(zip(self.commands + self.context, self.initial_env, strict=True))
        values.update({p: v for p, v in commands.items() if p in values})
        values.update({p: v for p, v in context.items() if p in values})
        return tuple(values[p] for p in self.commands + self.context)

    def measured_of(self, values: Mapping[str, Value | None]) -> State:
        return tuple(values[p] for p in self.measured)  # type: ignore[misc]  # None: the session refused it before

    def commands_of(self, env: State) -> dict[str, Value]:
        return dict(zip(self.commands, env[:len(self.commands)], strict=True))

    def describe(self, m: State, env: State | None = None, *, context: bool = True) -> str:
        parts = [f"{p}={format_value(v)}" for p, v in zip(self.measured, m, strict=True)]
        if env is not None:
            named = self.commands + (self.context if context else ())
            parts = [f"{p}={format_value(v)}" for p, v in zip(named, env, strict=False)] + parts
        return ", ".join(parts)

    def describe_changes(self, before: State, after: State) -> str:
        return ", ".join(f"{p}: {format_value(a)} -> {format_value(b)}"
                         for p, a, b in zip(self.measured, before, after, strict=True) if a != b)

    def describe_change_set(self, changes: Iterable[Change]) -> str:
        return ", ".join(f"{self.paths[i]} := {format_value(v)}" for i, v in sorted(changes, key=lambda c: c[0]))

    # --- effects ----------------------------------------------------------------------------
    @staticmethod
    def _value(value: Value | Ref, state: State, index: Mapping[str, int]) -> Value:
        return state[index[value.path]] if isinstance(value, Ref) else value

    def changes(self, effect: Effect, outcome: int, state: State) -> frozenset[Change]:
        """The measured values an outcome changes in `state` (empty: it would change nothing)."""
        return frozenset((i, v) for i, raw in effect.outcomes[outcome]
                         if state[i] != (v := self._value(raw, state, self.index)))

    def enabled(self, m: State, env: State) -> list[Effect]:
        state = m + env
        return [e for e in self.effects if e.guard(state)]

    def observable(self, effect: Effect, m: State, env: State) -> bool:
        """Whether every outcome would change something: only then can its absence be seen."""
        state = m + env
        return all(self.changes(effect, k, state) for k in range(len(effect.outcomes)))

    def describe_outcomes(self, effect: Effect, state: State) -> str:
        texts = []
        for k in range(len(effect.outcomes)):
            changed = self.changes(effect, k, state)
            texts.append(self.describe_change_set(changed) if changed else "(no change)")
        return " or ".join(texts)

    def explain(self, m0: State, start: InFlight | None, envs: Sequence[State], m1: State
                ) -> tuple[set[InFlight | None], set[str]]:
        """How the measured state can go from `m0` to `m1` within `max_effect_steps` effect starts.

        `start`: an outcome in flight at `m0` (its remaining assignments may show up first).
        `envs`: the environment at `m0`, and at `m1` when it changed: it switches once, anywhere
        on the way. Returns what may be in flight at `m1` (None: nothing), empty when the change
        is not explained, and the effects started on some explaining path."""
        memo: dict[tuple[State, InFlight | None, int, int], tuple[frozenset[InFlight | None], frozenset[str]]] = {}
        last = len(envs) - 1

        def search(m: State, flight: InFlight | None, phase: int, budget: int
                   ) -> tuple[frozenset[InFlight | None], frozenset[str]]:
            key = (m, flight, phase, budget)
            if key in memo:
                return memo[key]
            results: set[InFlight | None] = set()
            fired: set[str] = set()
            if m == m1 and phase == last:
                results.add(flight)
            if phase < last:
                r, f = search(m, flight, phase + 1, budget)
                results |= r
                fired |= f
            if flight is not None:
                for change in flight.remaining:
                    rest = flight.remaining - {change}
                    nxt = InFlight(flight.effect, flight.outcome, rest) if rest else None
                    r, f = search(_set(m, change), nxt, phase, budget)
                    results |= r
                    fired |= f
            elif budget > 0:
                state = m + envs[phase]
                for effect in self.effects:
                    if not effect.guard(state):
                        continue
                    for k in range(len(effect.outcomes)):
                        changed = self.changes(effect, k, state)
                        for change in changed:  # an outcome shows at least one of its changes at once
                            rest = changed - {change}
                            nxt = InFlight(effect.name, k, rest) if rest else None
                            r, f = search(_set(m, change), nxt, phase, budget - 1)
                            if r:
                                results |= r
                                fired |= f | {effect.name}
            memo[key] = (frozenset(results), frozenset(fired))
            return memo[key]

        results, fired = search(m0, start, 0, self.max_effect_steps)
        return set(results), set(fired)

    # --- reachability -----------------------------------------------------------------------
    @cached_property
    def reachable_measured(self) -> frozenset[State] | None:
        """Every measured state the model can reach from its initial one, with any commands and any
        context (the tester sends any command; other resources may be anywhere). None: too many."""
        combos: list[list[State]] = []
        for effect in self.effects:
            domains = [self.model.var(self.paths[i]).domain.values for i in effect.env_reads]
            size = 1
            for d in domains:
                size *= len(d)
            if size > REACHABILITY_LIMIT // 10:
                return None
            envs = []
            for values in itertools.product(*domains):
                env_values = list(self.initial_env)
                for i, v in zip(effect.env_reads, values, strict=True):
                    env_values[i - self.n_measured] = v
                envs.append(tuple(env_values))
            combos.append(envs)
        seen = {self.initial_measured}
        frontier = [self.initial_measured]
        while frontier:
            m = frontier.pop()
            for effect, envs in zip(self.effects, combos, strict=True):
                for env in envs:
                    state = m + env
                    if not effect.guard(state):
                        continue
                    for k in range(len(effect.outcomes)):
                        after = m
                        for change in self.changes(effect, k, state):
                            after = _set(after, change)
                        if after not in seen:
                            seen.add(after)
                            frontier.append(after)
                            if len(seen) > REACHABILITY_LIMIT:
                                return None
        return frozenset(seen)

    def is_reachable(self, m: State) -> bool:
        reachable = self.reachable_measured
        return reachable is None or m in reachable

    # --- commands the controller would send ---------------------------------------------------
    def model_commands(self, m: State, env: State) -> list[dict[str, Value]]:
        """The command states the resource's deliberate and automatic transitions would send from
        here (each enabled one applied to the current commands), keyed by short name; no repeats,
        and never the current command."""
        state = m + env
        current = self.commands_of(env)
        found: list[dict[str, Value]] = []
        for t, guard in zip(self.controls, self._control_guards, strict=True):
            if not guard(state):
                continue
            after = dict(current)
            for action in t.actions:
                if action.path in after:
                    after[action.path] = self._value(action.value, state, self.index)
            if after != current and after not in found:
                found.append(after)
        return [{p.split(".", 1)[1]: v for p, v in c.items()} for c in found]


def _set(m: State, change: Change) -> State:
    i, value = change
    return (*m[:i], value, *m[i + 1:])
