"""The engine's step semantics, compiled for search.

In a state where an automatic ability transition is enabled, the only step is the
first enabled one in model order (`CompiledModel.close` fires them one at a time);
otherwise the steps are the enabled effect outcomes and the enabled deliberate
transitions whose effect no effect already due would overtake (`RaceCheck`). The
search works on *macro-steps*: one non-automatic step followed by the urgent automatic
chain it triggers. Every micro state of the chain is checked (a forbidden one cuts the
chain), so macro-steps describe exactly the micro-step graph.
A goal counts only in a stable state (`stable_goal`): the engine fires the pending
automatics before it looks at any goal, so a plan never relies on one waiting.

Guards are inlined into generated functions: one call tells which moves are enabled,
and one call per written-variable set finds the first enabled automatic among the
only candidates that can have become enabled since the last stable state (those
reading a written variable).
"""

from __future__ import annotations

import contextlib
import operator
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass

from common.model import TransitionKind
from common.model.compiled import MAX_AUTOMATIC_STEPS, CompiledModel, CompiledTransition, State, predicate_source

Move = tuple[int, int]  # (CompiledTransition.number, outcome index)
StateTest = Callable[[State], bool]
CYCLE_CHECK_AFTER = 64  # chain length from which repeated states are looked for (automatic cycles)
RACE_ANSWERS_KEPT = 200_000  # RaceCheck answers by projected state


@dataclass(frozen=True)
class Race:
    """A command starts effect `started` while effect `due` is enabled, and one firing first disables the other."""

    started: CompiledTransition
    due: CompiledTransition
    started_disables_due: bool  # else `due` firing first disables `started`


RacePairs = tuple[tuple[CompiledTransition, tuple[CompiledTransition, ...]], ...]


def races_after(after: State, pairs: RacePairs) -> Iterator[Race]:
    """The races in `after`, the state a command leads to: each effect it starts against each rival due."""
    for f, rivals in pairs:
        if not f.guard(after):
            continue
        for e in rivals:
            if not e.guard(after):
                continue
            if any(not e.guard(o(after)) for o in f.outcomes):
                yield Race(f, e, True)
            elif any(not f.guard(o(after)) for o in e.outcomes):
                yield Race(f, e, False)


class RaceCheck:
    """Commands whose effect would race an effect already under way.

    Effects take the time they take. A plan may not give a command whose effect and an
    effect already due could each undo the other's condition: the changer told to lock on
    the tool at the dock and the robot sent home, in either order, count on the lock closing
    before the robot leaves; the real changer may lock on nothing. `races(state, t)`:
    deliberate `t` would start an effect f while an effect e is due, and e firing first
    disables f, or f firing first disables e. The planner asks it of predicted states; the
    engine asks `overtaking` of the measured state, where an effect may be due that the plan
    predicted for later (controller/engine.py holds the command until that effect happened).
    """

    def __init__(self, compiled: CompiledModel, disabled: frozenset[str] = frozenset(),
                 timed_races: TimedRaces | None = None) -> None:
        """`timed_races`: the races the timed check found (shared by every set of disabled resources)."""
        self.timed_races = timed_races if timed_races is not None else TimedRaces()
        effects = [e for e in compiled.effects if not (e.resources & disabled)]
        self._watch: dict[int, RacePairs] = {}
        # The answer depends only on the state after t on the variables the pairs' guards and outcomes
        # read (an outcome writes constants or copies of what its transition reads): a search asks the
        # same few projections thousands of times, so answers are kept by (t, projection).
        self._relevant: dict[int, Callable[[State], object]] = {}
        self._known: dict[tuple[int, object], bool] = {}
        for t in compiled.deliberate:
            pairs = []
            relevant: set[int] = set()
            for f in effects:
                if f.reads & t.writes:
                    rivals = tuple(e for e in effects if e is not f and (e.writes & f.reads or f.writes & e.reads))
                    if rivals:
                        pairs.append((f, rivals))
                        relevant |= f.reads.union(*(e.reads for e in rivals))
            if pairs:
                self._watch[t.number] = tuple(pairs)
                self._relevant[t.number] = operator.itemgetter(*sorted(relevant))

    def watched(self, t: CompiledTransition) -> RacePairs:
        """The (effect t may start, its rivals) pairs `races` checks for deliberate `t` (the PDDL export needs them)."""
        return self._watch.get(t.number, ())

    def races(self, state: State, t: CompiledTransition) -> bool:
        pairs = self._watch.get(t.number)
        if pairs is None:
            return False
        after = t.outcomes[0](state)
        key = (t.number, self._relevant[t.number](after))
        known = self._known.get(key)
        if known is None:
            if len(self._known) >= RACE_ANSWERS_KEPT:  # memory stays bounded in a long run
                self._known.clear()
            known = self._known[key] = any(races_after(after, pairs))
        return known

    def outrun(self, state: State, t: CompiledTransition) -> bool:
        """Step `t` (not automatic) in `state` would come after an effect due there that the timed check saw
        take its condition away first (`TimedRaces`)."""
        return self.timed_races.outrun(state, t)

    def overtaking(self, state: State, t: CompiledTransition) -> list[Race]:
        """The effects enabled in `state` that an effect started by `t` would disable, were it first."""
        pairs = self._watch.get(t.number)
        if pairs is None:
            return []
        return [race for race in races_after(t.outcomes[0](state), pairs)
                if race.started_disables_due and race.due.guard(state)]


class TimedRaces:
    """Races a plan lost in time (controller/timed_check.py): step `victim` counted on effect `due`, enabled
    before it, waiting past it; the devices do not wait, and the effect came first. Planning on, `victim` is
    not taken while `due` is enabled: the plan that waits for the effect (the vacuum kept on until the feeder's
    sensor has registered; the nutrunner's reset before the operator is told to tighten pipe 2) is found instead
    of the same one again. Learned from the plans refused while the station runs; bounded by the model's size."""

    def __init__(self) -> None:
        self._due_before: dict[int, tuple[CompiledTransition, ...]] = {}  # victim number -> effects
        self.suspended = False  # planning as if none were known (`suspended_while`)

    def __bool__(self) -> bool:
        return bool(self._due_before) and not self.suspended

    @property
    def version(self) -> tuple[int, bool]:
        """Changes whenever a race is learnt or the known ones are suspended: what searches remembered by
        question (reuse.SearchMemory) are keyed on. Races are only ever added."""
        return sum(map(len, self._due_before.values())), self.suspended

    @contextlib.contextmanager
    def suspended_while(self) -> Iterator[None]:
        """Plan as if no race were known: when none but a plan that loses one reaches the goals, that plan is
        what the livelock watch (controller/livelock.py) sees fail and names."""
        self.suspended = True
        try:
            yield
        finally:
            self.suspended = False

    def known(self) -> Mapping[int, tuple[CompiledTransition, ...]]:
        """Victim transition number -> the effects it may not come after while they are due (none while
        suspended): what a member that compiles the moves ahead of time (the symbolic one) builds in."""
        return {} if self.suspended else dict(self._due_before)

    def forbid(self, victim: CompiledTransition, due: CompiledTransition) -> bool:
        """Forbid `victim` while `due` is enabled; False if it already was."""
        known = self._due_before.get(victim.number, ())
        if due in known:
            return False
        self._due_before[victim.number] = (*known, due)
        return True

    def blocking(self, state: State, t: CompiledTransition) -> tuple[CompiledTransition, ...]:
        """The effects due in `state` that `t` may not come after."""
        if self.suspended:
            return ()
        return tuple(e for e in self._due_before.get(t.number, ()) if e.guard(state))

    def outrun(self, state: State, t: CompiledTransition) -> bool:
        effects = self._due_before.get(t.number)
        return effects is not None and not self.suspended and any(e.guard(state) for e in effects)


@dataclass(frozen=True)
class Successor:
    state: State
    moves: tuple[Move, ...]  # the non-automatic step, then the automatics it triggered (micro steps)
    goal: bool  # the chain stopped early because `state` satisfies the goal


def _generate(name: str, body: list[str]) -> Callable[..., object]:
    namespace: dict[str, object] = {}
    exec(f"def {name}(s):\n" + "\n".join(f"    {line}" for line in body), namespace)
    return namespace[name]  # type: ignore[return-value]  # compiled by exec: the namespace holds objects


class StepSystem:
    """The ability transitions of a compiled model minus those touching a disabled resource."""

    def __init__(self, compiled: CompiledModel, disabled: frozenset[str] = frozenset(),
                 race: RaceCheck | None = None) -> None:
        self.compiled = compiled
        self.disabled = disabled
        self.by_number = compiled.transitions

        def allowed(t: CompiledTransition) -> bool:
            return not (t.resources & disabled)

        self.automatic: tuple[CompiledTransition, ...] = tuple(t for t in compiled.automatic if allowed(t))
        ability = {t.number for t in (*compiled.deliberate, *compiled.effects)}
        # Model order (deliberate and effect interleaved as declared) only decides ties between equal plans.
        self.controlled: tuple[CompiledTransition, ...] = tuple(
            t for t in compiled.transitions if t.number in ability and allowed(t)
        )
        self.moves: tuple[tuple[CompiledTransition, int], ...] = tuple(
            (t, o) for t in self.controlled for o in range(len(t.outcomes))
        )
        self.transitions: tuple[CompiledTransition, ...] = (*self.controlled, *self.automatic)
        self.race = race or RaceCheck(compiled, disabled)
        # Positions in `moves` of the moves enabled in a state where no automatic is: one generated call.
        self.enabled_positions: Callable[[State], list[int]] = self._enabled_function()
        self._readers: dict[int, list[int]] = {}
        for position, t in enumerate(self.automatic):
            for i in t.reads:
                self._readers.setdefault(i, []).append(position)
        self._first_all = self._first_function(range(len(self.automatic)))
        self._first_by_written: dict[frozenset[int], Callable[[State], int]] = {}

    # --- generated guard tests ---------------------------------------------------------
    def _source(self, t: CompiledTransition) -> str:
        return predicate_source(self.compiled.guard_of(t.source), self.compiled.index)

    def _enabled_function(self) -> Callable[[State], list[int]]:
        body = ["r = []"]
        position = 0
        for t in self.controlled:
            count = len(t.outcomes)
            indices = tuple(range(position, position + count))
            body.append(f"if {self._source(t)}: r.extend({indices!r})")
            position += count
        body.append("return r")
        return _generate("enabled", body)  # type: ignore[return-value]  # compiled by exec: the namespace holds objects

    def _first_function(self, positions: Iterable[int]) -> Callable[[State], int]:
        body = [f"if {self._source(self.automatic[p])}: return {p}" for p in sorted(positions)]
        body.append("return -1")
        return _generate("first", body)  # type: ignore[return-value]  # compiled by exec: the namespace holds objects

    def _first_after(self, written: frozenset[int]) -> Callable[[State], int]:
        function = self._first_by_written.get(written)
        if function is None:
            candidates = {p for i in written for p in self._readers.get(i, ())}
            function = self._first_function(candidates)
            self._first_by_written[written] = function
        return function

    # --- semantics -----------------------------------------------------------------------
    def first_automatic(self, state: State) -> CompiledTransition | None:
        """The automatic transition that must fire in `state`, if any (full check, no stability assumed)."""
        position = self._first_all(state)
        return None if position < 0 else self.automatic[position]

    def enabled_moves(self, state: State) -> list[tuple[CompiledTransition, int]]:
        """Deliberate transitions and effect outcomes enabled in a state where no automatic one is."""
        moves = self.moves
        return [moves[m] for m in self.enabled_positions(state)]

    def chain(
        self,
        state: State,
        moves: list[Move],
        written: frozenset[int] | None,
        goal: StateTest,
        forbidden: StateTest | None,
    ) -> Successor | None:
        """Follow the urgent automatic chain from `state` (already reached by `moves`).

        `written` is the set of variables written since the last stable state, or None
        when `state` is not known to follow one (the start), which checks every automatic.
        None is returned when the chain enters a forbidden state or never ends.
        """
        automatic = self.automatic
        seen: set[State] | None = None
        while True:
            if forbidden is not None and forbidden(state):
                return None
            if goal(state):
                return Successor(state, tuple(moves), True)
            position = self._first_all(state) if written is None else self._first_after(written)(state)
            if position < 0:
                return Successor(state, tuple(moves), False)
            t = automatic[position]
            state = t.outcomes[0](state)
            moves.append((t.number, 0))
            if written is not None:
                written = written | t.writes
            if len(moves) > CYCLE_CHECK_AFTER:
                if seen is None:
                    seen = set()
                if state in seen or len(moves) > MAX_AUTOMATIC_STEPS:
                    return None  # an automatic cycle: the engine would never get past it
                seen.add(state)

    def unblocking(self, state: State, moves: frozenset[Move]) -> frozenset[Move]:
        """The moves of the effects due in `state` that a learnt race makes one of `moves` wait for. A relaxed
        plan never holds them (the nutrunner going back to its dock matters to no goal), so a search that follows
        the relaxed plan's moves has to be told: the instruction for pipe 2 waits for the dock, the dock is next."""
        races = self.race.timed_races
        if not races:
            return frozenset()
        found: set[Move] = set()
        for number, _ in moves:
            for e in races.blocking(state, self.by_number[number]):
                found.update((e.number, o) for o in range(len(e.outcomes)))
        return frozenset(found)

    def successors(self, state: State, goal: StateTest, forbidden: StateTest | None) -> list[Successor]:
        """Macro-steps from a stable state (no automatic transition enabled)."""
        result = []
        chain, races = self.chain, self.race.races
        outrun = self.race.outrun if self.race.timed_races else None
        for t, o in self.enabled_moves(state):
            if t.kind is TransitionKind.DELIBERATE and races(state, t):
                continue
            if outrun is not None and outrun(state, t):
                continue
            found = chain(t.outcomes[o](state), [(t.number, o)], t.writes, goal, forbidden)
            if found is not None:
                result.append(found)
        return result


def stable_goal(compiled: CompiledModel, is_goal: StateTest, disabled: frozenset[str]) -> StateTest:
    """`is_goal`, and no automatic transition (of an enabled resource) is due: the engine would fire it first."""
    automatic = tuple(t for t in compiled.automatic if not (t.resources & disabled))

    def test(state: State) -> bool:
        return is_goal(state) and not any(t.guard(state) for t in automatic)

    return test


def settle(system: StepSystem, start: State, goal: StateTest,
           forbidden: StateTest | None) -> tuple[State, list[Move]] | Successor | None:
    """Where a search begins: a start that is not stable fires its automatics first whatever the plan.
    Returns (the stable root, the moves to it); or a Successor whose `goal` is set when those automatics
    already reach the goal; or None when they enter a forbidden state or never stop."""
    if system.first_automatic(start) is None:
        return start, []
    forced = system.chain(start, [], None, goal, forbidden)
    if forced is None or forced.goal:
        return forced
    return forced.state, list(forced.moves)

