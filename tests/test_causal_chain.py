"""The run's longest causal chain (controller/causal_chain.py), and the run's bound it makes (controller/cycle.py)."""

from __future__ import annotations

import heapq
import itertools

from common.model import Duration, Model, Phase, Resource, ability, command, measured, operation, parse_predicate
from common.model.compiled import CompiledModel, State
from controller.causal_chain import CausalChain
from deploy.local.inprocess import run_in_process

SECONDS = {"a": 1.0, "b": 2.0, "c": 2.5}


def relay() -> Model:
    """Three lamps: b may be switched on only once a is lit (a cause), c on its own."""
    resources = []
    for name in ("a", "b", "c"):
        on_c, on_m = command(f"{name}.on_c", initial=False), measured(f"{name}.on_m")
        switch = ability(f"{name}.switch",
                         enabled=Phase(~on_c & ~on_m, deliberate=f"{name}.on_c := true",
                                       guard="a.on_m" if name == "b" else True),
                         executing=Phase(on_c & ~on_m, effects=f"{name}.on_m := true"))
        resources.append(Resource(name, (on_c, on_m), (switch,), duration=Duration.fixed(SECONDS[name])))
    return Model("relay", tuple(resources),
                 operations=(operation("AllOn", "!a.on_m && !b.on_m && !c.on_m", "a.on_m && b.on_m && c.on_m"),))


def effect_seconds() -> dict[str, float]:
    return {f"{name}.switch.executing.effect": seconds for name, seconds in SECONDS.items()}


def fired(chain: CausalChain, compiled: CompiledModel, state: State, name: str) -> State:
    transition = compiled.by_name[name]
    assert transition.guard(state), name
    chain.fired([name])
    return transition.outcomes[0](state)


def test_an_effect_starts_when_what_its_guard_reads_was_written() -> None:
    compiled = CompiledModel(relay())
    chain = CausalChain(compiled, effect_seconds())
    state = fired(chain, compiled, compiled.initial(), "a.switch.enabled")
    lit = compiled.by_name["a.switch.executing.effect"].outcomes[0](state)
    chain.measured(state, lit)
    assert chain.longest == 1.0
    state = fired(chain, compiled, lit, "b.switch.enabled")  # reads a.on_m: starts at 1.0
    chain.measured(state, compiled.by_name["b.switch.executing.effect"].outcomes[0](state))
    assert chain.longest == 3.0


def test_independent_effects_do_not_add_up() -> None:
    compiled = CompiledModel(relay())
    chain = CausalChain(compiled, effect_seconds())
    state = fired(chain, compiled, compiled.initial(), "a.switch.enabled")
    state = fired(chain, compiled, state, "c.switch.enabled")
    both = compiled.by_name["c.switch.executing.effect"].outcomes[0](
        compiled.by_name["a.switch.executing.effect"].outcomes[0](state))
    chain.measured(state, both)  # one batch of measured values, two effects in it
    assert chain.longest == 2.5


def test_a_change_no_effect_explains_starts_no_chain() -> None:
    compiled = CompiledModel(relay())
    chain = CausalChain(compiled, effect_seconds())
    state = compiled.initial()
    lit = compiled.with_values(state, {"a.on_m": True})  # a restarted hub says so: no command made it
    chain.measured(state, lit)
    assert chain.longest == 0.0
    state = fired(chain, compiled, lit, "b.switch.enabled")
    chain.measured(state, compiled.by_name["b.switch.executing.effect"].outcomes[0](state))
    assert chain.longest == 2.0


def fastest_schedule(compiled: CompiledModel, goal: str, seconds: dict[str, float]) -> float:
    """Every timed execution of the model, explored: a command fires at any moment its whole guard (a supervisor's
    part included, if the model has one) holds, an effect happens its duration after its guard came to hold and
    stayed. The earliest time the goal (a predicate) holds."""
    reached = compiled.predicate(parse_predicate(goal))
    counter = itertools.count()
    Node = tuple[float, int, State, tuple[tuple[str, float], ...]]
    queue: list[Node] = [(0.0, next(counter), compiled.initial(), ())]
    seen: set[tuple[State, tuple[tuple[str, float], ...]]] = set()
    while queue:
        now, _, state, due = heapq.heappop(queue)
        if reached(state):
            return now
        if (state, due) in seen:
            continue
        seen.add((state, due))
        for command_ in compiled.deliberate:  # fire a command now
            if command_.guard(state):
                after = command_.outcomes[0](state)
                heapq.heappush(queue, (now, next(counter), after, _timers(compiled, after, due, now, seconds)))
        if due:  # or let time run to the next effect
            name, at = min(due, key=lambda d: d[1])
            after = compiled.by_name[name].outcomes[0](state)
            rest = tuple(d for d in due if d[0] != name)
            heapq.heappush(queue, (at, next(counter), after, _timers(compiled, after, rest, at, seconds)))
    raise AssertionError(f"{goal} is never reached")


def _timers(compiled: CompiledModel, state: State, due: tuple[tuple[str, float], ...], now: float,
            durations: dict[str, float]) -> tuple[tuple[str, float], ...]:
    running = dict(due)
    timers = []
    for effect in compiled.effects:
        if effect.guard(state):
            timers.append((effect.name, running.get(effect.name, now + durations[effect.name])))
    return tuple(sorted(timers))


def test_the_runs_bound_is_below_the_fastest_schedule_and_reaches_it_here() -> None:
    model = relay()
    best = fastest_schedule(CompiledModel(model), "a.on_m && b.on_m && c.on_m", effect_seconds())
    assert best == 3.0  # a then b; c beside them
    summary = run_in_process(model, seed=1)
    assert summary.finished, summary.reason
    assert summary.cycle is not None
    assert summary.cycle.chain == best  # the cause a -> b is the chain
    assert summary.cycle.bound <= best <= summary.cycle.cycle


def test_the_reference_runs_bound_follows_the_cycle_past_its_first_plan() -> None:
    from common.stations import load_model

    summary = run_in_process(load_model(), seed=1, delays={"human": 20.0, "ur": 1.5, "nr": 2.0})
    assert summary.finished, summary.reason
    cycle = summary.cycle
    assert cycle is not None and cycle.first is not None
    # The first plan brings the engine and the tools; the chain goes on through the frame, the bolts placed
    # (the operator's 20 s tasks), the filters and the pipes.
    assert cycle.chain > 10 * cycle.first.chain
    assert max(cycle.chain, cycle.busiest_work) < cycle.bound == cycle.apart <= cycle.cycle
    assert "the work the specifications keep apart" in cycle.lines()[0]
