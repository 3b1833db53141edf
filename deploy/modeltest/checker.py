"""Checks a stream of observed states of one resource against its model (DESIGN.md §9).

After each observation:

* (c) every change of the measured variables must be explained by effect transitions
  enabled on the way (at most `max_effect_steps` of them between two samples; an
  outcome's assignments may show up over several samples);
* (b) an effect that is enabled in the observed state (its guard over the resource's
  variables, the applied command and the last known values of the other resources)
  must show one of its outcomes within the deadline, unless the command changes
  first; an outcome seen in part must be seen whole within the deadline.

A violation is raised as `Violation` carrying a `Finding`. The session turns every
Violation into one `ExampleFailure` raised from one place, so that Hypothesis shrinks
every kind of finding as one bug (it tells bugs apart by exception type and location).
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field

from common.model.predicates import format_value

from .oracle import Effect, InFlight, ResourceOracle, State


class FindingKind(enum.StrEnum):
    """What a model-based test found wrong (the word starts the finding's report)."""

    MIRROR = "command not mirrored"
    EFFECT_NOT_OBSERVED = "effect not observed"
    UNEXPLAINED_CHANGE = "change not allowed by the model"
    HUB_STATUS = "hub status"
    START_STATE = "state not reachable in the model"


@dataclass(frozen=True)
class Finding:
    kind: FindingKind
    message: str  # one line: what was expected and what was seen
    effect: str = ""  # the phase whose effect was expected (`nr.tighten.resetting`), if any
    guard: str = ""  # that effect's guard
    expected: tuple[str, ...] = ()  # the assignments that were expected (`nr.tqr_m := false`)
    observed: str = ""  # the last observed state
    details: tuple[str, ...] = ()  # further lines (effects that were enabled, ...)

    def describe(self) -> str:
        lines = [f"{self.kind}: {self.message}"]
        lines += [f"  {d}" for d in self.details]
        if self.observed:
            lines.append(f"last observed state: {self.observed}")
        return "\n".join(lines)


class Violation(AssertionError):
    def __init__(self, finding: Finding) -> None:
        self.finding = finding
        super().__init__(finding.describe())


def violation(finding: Finding) -> Violation:
    return Violation(finding)


@dataclass(frozen=True)
class Observation:
    """One state sample of the tested resource, as the checker needs it."""

    time: float  # local monotonic clock at receipt
    measured: State
    env: State  # applied commands (from the mirror), then context values

    @property
    def key(self) -> tuple[State, State]:
        return self.measured, self.env


@dataclass
class _Timer:
    since: float
    commands: State
    state: State


@dataclass
class Checker:
    """Judges observations in order. A sample's measured values and its mirror may be up to `lag`
    seconds apart (the hub publishes a new mirror with the values it read before applying it), so
    a sample is judged once `lag` has passed, and an effect may have fired under any command seen
    within `lag` of the two samples it lies between."""

    oracle: ResourceOracle
    deadline: float
    lag: float = 0.06
    start_time: float = 0.0
    last: Observation | None = None  # the last judged observation
    flights: dict[InFlight | None, float] = field(default_factory=dict)  # hypotheses -> since
    timers: dict[str, _Timer] = field(default_factory=dict)  # enabled effects -> since
    last_change: float = 0.0
    trace: list[str] = field(default_factory=list)  # what was observed, for the report
    pending: deque[Observation] = field(default_factory=deque)  # not judged yet
    recent: deque[Observation] = field(default_factory=deque)  # judged, within `lag` of the last

    # --- lifecycle ------------------------------------------------------------------------
    def start(self, first: Observation) -> None:
        """Check from `first` on: nothing is in flight there."""
        self.start_time = first.time
        self.last = first
        self.flights = {None: first.time}
        self.timers = {}
        self.last_change = first.time
        self.pending.clear()
        self.recent = deque([first])
        self.trace = [f"{self._t(first.time)} {self.oracle.describe(first.measured, first.env, context=False)}"]
        self._arm_timers(first, fired=set())

    def note(self, time: float, text: str) -> None:
        self.trace.append(f"{self._t(time)} {text}")

    def _t(self, time: float) -> str:
        return f"+{time - self.start_time:.2f}s"

    @property
    def quiescent(self) -> bool:
        """Nothing in flight, no effect enabled, nothing new waiting to be judged: the model expects no change."""
        assert self.last is not None
        return (set(self.flights) == {None} and not self.timers
                and all(p.key == self.last.key for p in self.pending))

    @property
    def latest(self) -> Observation:
        """The newest observation, judged or not."""
        assert self.last is not None
        return self.pending[-1] if self.pending else self.last

    def describe_last(self) -> str:
        latest = self.latest
        return self.oracle.describe(latest.measured, latest.env)

    # --- observations -----------------------------------------------------------------------
    def observe(self, obs: Observation) -> None:
        assert self.last is not None, "start() first"
        self.pending.append(obs)
        self.check_time(obs.time)

    def check_time(self, now: float) -> None:
        """Judge what is older than `lag`, then raise when an expectation is overdue at `now`."""
        while self.pending and self.pending[0].time <= now - self.lag:
            self._judge(self.pending.popleft())
        self._check_overdue(now - self.lag)

    def _envs_around(self, prev: Observation, obs: Observation) -> list[State]:
        """The commands and context that may have held between `prev` and `obs`, in order."""
        seen = [o for o in self.recent if o.time >= prev.time - self.lag] + [prev, obs]
        seen += [o for o in self.pending if o.time <= obs.time + self.lag]
        envs: list[State] = []
        for o in sorted(seen, key=lambda o: o.time):
            if not envs or envs[-1] != o.env:
                envs.append(o.env)
        return envs

    def _judge(self, obs: Observation) -> None:
        prev = self.last
        assert prev is not None
        oracle = self.oracle
        self.last = obs
        self.recent.append(obs)
        while self.recent and self.recent[0].time < obs.time - 2 * self.lag:
            self.recent.popleft()
        if obs.env[:len(oracle.commands)] != prev.env[:len(oracle.commands)]:
            changed = ", ".join(f"{p} := {format_value(v)}" for p, v in oracle.commands_of(obs.env).items())
            self.note(obs.time, f"hub applied {changed}")
        if obs.key == prev.key:
            return
        fired: set[str] = set()
        if obs.measured != prev.measured:
            envs = self._envs_around(prev, obs)
            flights: dict[InFlight | None, float] = {}
            for start, since in self.flights.items():
                results, started = oracle.explain(prev.measured, start, envs, obs.measured)
                fired |= started
                for result in results:
                    continued = (result is not None and start is not None and result.effect == start.effect
                                 and result.outcome == start.outcome and result.remaining <= start.remaining)
                    when = since if continued else obs.time
                    flights[result] = max(flights.get(result, when), when)
            self.last_change = obs.time
            self.note(obs.time, oracle.describe_changes(prev.measured, obs.measured))
            if not flights:
                raise violation(self._unexplained(prev, obs, envs))
            self.flights = flights
        self._arm_timers(obs, fired)

    def _arm_timers(self, obs: Observation, fired: set[str]) -> None:
        for name in fired:
            self.timers.pop(name, None)
        if None not in self.flights:
            return  # mid-effect: the observed state is no state of the model
        commands = obs.env[:len(self.oracle.commands)]
        for effect in self.oracle.effects:
            if effect.guard(obs.measured + obs.env) and self.oracle.observable(effect, obs.measured, obs.env):
                timer = self.timers.get(effect.name)
                if timer is None or timer.commands != commands:
                    self.timers[effect.name] = _Timer(obs.time, commands, obs.measured + obs.env)
            else:
                self.timers.pop(effect.name, None)

    def _check_overdue(self, now: float) -> None:
        overdue = {f: since for f, since in self.flights.items()
                   if f is not None and now - since > self.deadline}
        if overdue and len(overdue) == len(self.flights):
            flight, since = min(overdue.items(), key=lambda item: item[1])
            assert flight is not None
            raise violation(self._flight_overdue(flight, since))
        for flight in overdue:
            del self.flights[flight]
        if None in self.flights:
            for name, timer in self.timers.items():
                if now - timer.since > self.deadline:
                    raise violation(self._timer_overdue(self.oracle.effect_by_name[name], timer))

    # --- findings ---------------------------------------------------------------------------
    def _flight_overdue(self, flight: InFlight, since: float) -> Finding:
        effect = self.oracle.effect_by_name[flight.effect]
        expected = tuple(self.oracle.describe_change_set([c]) for c in sorted(flight.remaining, key=lambda c: c[0]))
        return Finding(
            FindingKind.EFFECT_NOT_OBSERVED,
            f"{effect.describe_guard()}  expected  {', '.join(expected)}  within {self.deadline:g} s of the rest of "
            f"that outcome ({self._t(since)}): not observed",
            effect=effect.phase, guard=str(effect.transition.guard), expected=expected,
            observed=self.describe_last())

    def _timer_overdue(self, effect: Effect, timer: _Timer) -> Finding:
        outcomes = self.oracle.describe_outcomes(effect, timer.state)
        return Finding(
            FindingKind.EFFECT_NOT_OBSERVED,
            f"{effect.describe_guard()}  expected  {outcomes}  within {self.deadline:g} s of its guard holding "
            f"({self._t(timer.since)}): not observed",
            effect=effect.phase, guard=str(effect.transition.guard), expected=tuple(outcomes.split(" or ")),
            observed=self.describe_last())

    def _unexplained(self, prev: Observation, obs: Observation, envs: list[State]) -> Finding:
        oracle = self.oracle
        details = []
        best: tuple[int, Effect, tuple[str, ...]] | None = None
        for env in envs:
            for effect in oracle.enabled(prev.measured, env):
                state = prev.measured + env
                details.append(f"enabled: {effect.describe_guard()}  gives  {oracle.describe_outcomes(effect, state)}")
                for k in range(len(effect.outcomes)):
                    after = dict(oracle.changes(effect, k, state))
                    missing = tuple(oracle.describe_change_set([(i, v)]) for i, v in sorted(after.items())
                                    if obs.measured[i] != v)
                    extra = sum(1 for i in range(oracle.n_measured)
                                if i not in after and obs.measured[i] != prev.measured[i])
                    score = len(missing) + extra
                    if best is None or score < best[0]:
                        best = (score, effect, missing)
        if not details:
            details.append(f"no effect of {oracle.resource.name} is enabled in the previous state")
        message = (f"{oracle.describe_changes(prev.measured, obs.measured)} is not explained by "
                   f"{oracle.max_effect_steps} or fewer effect steps from the previous observed state "
                   f"({oracle.describe(prev.measured, prev.env)})")
        effect_name = guard = ""
        expected: tuple[str, ...] = ()
        if best is not None and best[2]:
            _, effect, expected = best
            effect_name, guard = effect.phase, str(effect.transition.guard)
            message += f"; nearest: {effect.describe_guard()}  expected  {', '.join(expected)}"
        return Finding(FindingKind.UNEXPLAINED_CHANGE, message, effect=effect_name, guard=guard, expected=expected,
                       observed=oracle.describe(obs.measured, obs.env), details=tuple(details))

