"""Supervisor synthesis from forbidden-state specifications.

Effects (what devices do by themselves) and automatic transitions (which fire
whenever enabled) are uncontrollable. The bad states of a specification are its
forbidden states plus every state from which uncontrollable transitions can reach
them: the least fixpoint of `bad := bad || guard_e && wp(e, bad)`, computed over
cubes (`controller/cubes.py`) with implied cubes pruned, which keeps it exact and
small. A deliberate transition then gets the extra guard `!wp(t, bad)`: it never
fires into a bad state. A model whose initial state is already bad cannot be
controlled: it is refused with the uncontrollable trace into the forbidden state.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from common.model import Model, Predicate, Specification, TransitionKind, all_of, any_of, apply_all
from common.model.compiled import GuardSet
from common.model.rewrite import simplify

from .cubes import Cube, before, conjoin, holds, implies, merge, prune, to_cubes, to_predicate

MAX_BAD_CUBES = 20_000
TRACE_STATE_LIMIT = 200_000


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
    guards: GuardSet = field(default_factory=GuardSet)  # deliberate transition -> extra guard (and its specs)
    bad: dict[str, list[Cube]] = field(default_factory=dict)  # specification -> its bad states
    forbidden: Predicate | None = None  # disjunction of the specifications, for the planner
    converged: dict[str, bool] = field(default_factory=dict)

    def explain(self, transition: str) -> str:
        guard = self.guards.get(transition)
        return "no synthesized guard" if guard is None else str(guard)


def bad_states(model: Model, spec: Specification) -> tuple[list[Cube], bool]:
    domains = {p: v.domain for p, v in model.variables.items()}
    uncontrollable = [
        (t, outcome, to_cubes(t.guard, domains), {a.path for a in outcome})
        for t in model.ability_transitions if t.kind is not TransitionKind.DELIBERATE
        for outcome in t.outcomes
    ]
    bad = merge(to_cubes(spec.forbidden, domains), domains)
    frontier = list(bad)
    while frontier:
        found: list[Cube] = []
        for cube in frontier:
            for _t, outcome, guard_cubes, written in uncontrollable:
                if written.isdisjoint(cube):
                    continue  # this transition cannot make the cube true
                for pre in before(cube, outcome, domains):
                    for g in guard_cubes:
                        candidate = conjoin(g, pre)
                        if candidate is not None and not any(implies(candidate, b) for b in bad) \
                                and not any(implies(candidate, f) for f in found):
                            found.append(candidate)
        if not found:
            return bad, True
        previous = bad
        bad = merge(bad + prune(found), domains)
        # Cubes that merging widened are new too: their predecessors are looked at next round.
        frontier = [c for c in bad if not any(implies(c, old) for old in previous)]
        if len(bad) > MAX_BAD_CUBES:
            return bad, False
    return bad, True


def synthesize(model: Model) -> Supervisor:
    supervisor = Supervisor()
    if not model.specifications:
        return supervisor
    domains = {p: v.domain for p, v in model.variables.items()}
    initial = model.initial_state()
    for spec in model.specifications:
        bad, converged = bad_states(model, spec)
        supervisor.bad[spec.name] = bad
        supervisor.converged[spec.name] = converged
        if holds(bad, initial):
            raise SynthesisError(spec, counterexample(model, spec))
    for t in model.ability_transitions:
        if t.kind is not TransitionKind.DELIBERATE:
            continue
        written = t.written()
        extra: list[Predicate] = []
        specs: list[str] = []
        for spec in model.specifications:
            bad = supervisor.bad[spec.name]
            into_bad = merge([pre for cube in bad if not written.isdisjoint(cube)
                              for pre in before(cube, t.actions, domains)], domains)
            if into_bad:
                extra.append(simplify(~to_predicate(into_bad, domains)))
                specs.append(spec.name)
        if extra:
            supervisor.guards[t.name] = simplify(all_of(*extra))
            supervisor.guards.specs[t.name] = tuple(specs)
    supervisor.forbidden = simplify(any_of(*(s.forbidden for s in model.specifications)))
    return supervisor


def counterexample(model: Model, spec: Specification) -> list[str]:
    """Breadth-first over uncontrollable transitions from the initial state into the forbidden state."""
    uncontrollable = [t for t in model.ability_transitions if t.kind is not TransitionKind.DELIBERATE]
    start = model.initial_state()
    paths = tuple(start)
    key = tuple(start.values())
    parents: dict[tuple, tuple[tuple | None, str]] = {key: (None, "")}
    queue = deque([start])
    while queue and len(parents) < TRACE_STATE_LIMIT:
        state = queue.popleft()
        skey = tuple(state[p] for p in paths)
        if spec.forbidden.eval(state):
            trace = []
            while parents[skey][0] is not None:
                parent, label = parents[skey]
                trace.append(label)
                skey = parent  # type: ignore[assignment]  # the root's parent is None, never reached here
            return list(reversed(trace))
        for t in uncontrollable:
            if not t.guard.eval(state):
                continue
            for outcome in t.outcomes:
                nxt = apply_all(outcome, state)
                nkey = tuple(nxt[p] for p in paths)
                if nkey not in parents:
                    parents[nkey] = (skey, f"{t.name} [{t.kind.value}]: {'; '.join(str(a) for a in outcome)}")
                    queue.append(nxt)
    return ["(the forbidden state is further away than the search bound)"]
