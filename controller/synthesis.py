"""Supervisor synthesis from forbidden-state specifications.

Effects (what devices do by themselves) and automatic transitions (which fire
whenever enabled) are uncontrollable. The bad states of a specification are its
forbidden states plus every state from which uncontrollable transitions can reach
them: the fixpoint of `bad := bad || guard_e && wp(e, bad)`, computed symbolically.
A deliberate transition then gets the extra guard `!wp(t, bad)`: it never fires into
a bad state. A model whose initial state is already bad cannot be controlled: it is
refused with the uncontrollable trace that leads into the forbidden state.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from common.model import Model, Predicate, Specification, TransitionKind, all_of, any_of, apply_all
from common.model.predicates import Const, Or
from common.model.rewrite import after, simplify

MAX_ROUNDS = 12
TRACE_STATE_LIMIT = 50_000


class SynthesisError(ValueError):
    def __init__(self, spec: Specification, trace: list[str]) -> None:
        self.spec, self.trace = spec, trace
        steps = "\n".join(f"    {i + 1}. {line}" for i, line in enumerate(trace)) or "    (the initial state)"
        super().__init__(
            f"specification {spec.name!r} cannot be met: uncontrollable transitions lead from the initial state "
            f"into the forbidden state `{spec.forbidden}`:\n{steps}"
        )


@dataclass
class Supervisor:
    guards: dict[str, Predicate] = field(default_factory=dict)  # deliberate transition -> extra guard
    bad: dict[str, Predicate] = field(default_factory=dict)  # specification -> its bad states
    forbidden: Predicate | None = None  # disjunction of the specifications, for the planner
    converged: dict[str, bool] = field(default_factory=dict)


def _disjuncts(p: Predicate) -> list[Predicate]:
    if isinstance(p, Const) and not p.value:
        return []
    return list(p.items) if isinstance(p, Or) else [p]


def bad_states(model: Model, spec: Specification) -> tuple[Predicate, bool]:
    uncontrollable = [t for t in model.ability_transitions if t.kind is not TransitionKind.DELIBERATE]
    terms = _disjuncts(simplify(spec.forbidden))
    frontier = list(terms)
    for _ in range(MAX_ROUNDS):
        new_terms: list[Predicate] = []
        for t in uncontrollable:
            for outcome in t.outcomes:
                touched = {a.path for a in outcome}
                for term in frontier:
                    if not (term.paths() & touched):
                        continue  # the transition cannot make this term true
                    pre = simplify(all_of(t.guard, after(term, outcome)))
                    for d in _disjuncts(pre):
                        if d not in terms and d not in new_terms:
                            new_terms.append(d)
        if not new_terms:
            return simplify(any_of(*terms)), True
        terms += new_terms
        frontier = new_terms
    return simplify(any_of(*terms)), False


def synthesize(model: Model) -> Supervisor:
    supervisor = Supervisor()
    if not model.specifications:
        return supervisor
    initial = model.initial_state()
    for spec in model.specifications:
        bad, converged = bad_states(model, spec)
        supervisor.bad[spec.name] = bad
        supervisor.converged[spec.name] = converged
        if bad.eval(initial):
            raise SynthesisError(spec, counterexample(model, spec))
    for t in model.ability_transitions:
        if t.kind is not TransitionKind.DELIBERATE:
            continue
        written = t.written()
        extra = []
        for spec in model.specifications:
            bad = supervisor.bad[spec.name]
            if not (bad.paths() & written):
                continue
            guard = simplify(~after(bad, t.actions))
            if not (isinstance(guard, Const) and guard.value):
                extra.append(guard)
        if extra:
            supervisor.guards[t.name] = simplify(all_of(*extra))
    supervisor.forbidden = simplify(any_of(*(s.forbidden for s in model.specifications)))
    return supervisor


def counterexample(model: Model, spec: Specification) -> list[str]:
    """Breadth-first over uncontrollable transitions from the initial state into the forbidden state."""
    uncontrollable = [t for t in model.ability_transitions if t.kind is not TransitionKind.DELIBERATE]
    start = model.initial_state()
    key = tuple(sorted(start.items()))
    parents: dict[tuple, tuple[tuple | None, str]] = {key: (None, "")}
    queue = deque([start])
    while queue and len(parents) < TRACE_STATE_LIMIT:
        state = queue.popleft()
        skey = tuple(sorted(state.items()))
        if spec.forbidden.eval(state):
            trace = []
            while parents[skey][0] is not None:
                parent, label = parents[skey]
                trace.append(label)
                skey = parent  # type: ignore[assignment]
            return list(reversed(trace))
        for t in uncontrollable:
            if not t.guard.eval(state):
                continue
            for outcome in t.outcomes:
                nxt = apply_all(outcome, state)
                nkey = tuple(sorted(nxt.items()))
                if nkey not in parents:
                    parents[nkey] = (skey, f"{t.name} [{t.kind.value}]: {'; '.join(str(a) for a in outcome)}")
                    queue.append(nxt)
    return ["(a longer uncontrollable path than the search bound; the initial state satisfies the bad states)"]
