"""One example of a model-based test: a drawn command sequence, checked, that ends at home.

Every example starts by commanding the model's initial command values and waiting for
the device to come to rest there (unchecked: it only brings the device home); that rest
state must be one the model can reach. Then each step sends a command (one the model's
deliberate or automatic transitions would send from the observed state, or any
in-domain one) and either waits until the model expects nothing more ("settle") or
holds briefly ("brief", so that the next command interrupts what is under way). The
example ends with the initial command values again, settled and checked like any step,
so that what a sequence leaves behind is judged within that sequence. The checker
(checker.py) judges every state sample against the model.

A device that failed is in general in a state its model cannot reach (the paper's
nutrunner keeps torque-reached high), so the next example would not start where the
model says it can: it is *tainted*. A `reset` callable (restart an emulated hub: a
power cycle) clears that; without one the session waits for the device to come back
to a reachable state by itself and skips the examples until it does.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from hypothesis import strategies as st

from common.model import Value
from common.model.predicates import format_value
from common.wire.messages import HubStatus

from .checker import Checker, Finding, FindingKind, Observation, Violation, violation
from .link import ResourceLink, StateSample
from .oracle import ResourceOracle


class Wait(enum.Enum):
    """What a step does after its command."""

    SETTLE = "settle"  # waits until the device is at rest (Options.quiet)
    BRIEF = "brief"  # holds the command briefly (Options.brief), then the next one


class Source(enum.Enum):
    """Where a step's command comes from."""

    MODEL = "model"  # one the model's transitions would send
    ANY = "any"  # any values in their domains
    HOME = "home"  # the initial values: every example ends there
POLL_S = 0.02


@dataclass(frozen=True)
class Options:
    examples: int = 20  # Hypothesis examples (command sequences)
    max_steps: int = 6  # commands per example
    deadline: float = 2.0  # seconds for each expectation (mirror, effect)
    quiet: float = 0.15  # "settle": the device is at rest when nothing changed this long
    brief: float = 0.1  # "brief": hold a command this long before the next one
    max_effect_steps: int = 3  # effect steps allowed between two state samples
    sample_lag: float = 0.06  # a sample's measured values may be this much older or newer than its mirror
    model_share: int = 3  # of every 4 commands, this many come from the model's transitions when it has any
    seed: int | None = None  # Hypothesis seed (None: random)
    startup_timeout: float = 10.0  # waiting for the hub's first state (and after a reset)
    stale_after: float = 2.0  # no state sample for this long: the hub is gone

    def __post_init__(self) -> None:
        for name in ("deadline", "quiet", "brief", "startup_timeout", "stale_after", "sample_lag"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.examples < 1 or self.max_steps < 1:
            raise ValueError("examples and max_steps must be 1 or more")
        if not 0 <= self.model_share <= 4:
            raise ValueError(f"model_share must be within 0..4, got {self.model_share}")


@dataclass(frozen=True)
class Step:
    command: dict[str, Value]  # every command variable, by short name
    wait: Wait
    source: Source

    def describe(self, resource: str) -> str:
        values = ", ".join(f"{resource}.{name} := {format_value(v)}" for name, v in self.command.items())
        how = {Source.MODEL: "the model's command", Source.ANY: "an arbitrary command",
               Source.HOME: "back to the initial command"}[self.source]
        wait = "wait until settled" if self.wait is Wait.SETTLE else "hold briefly"
        return f"{values}   ({how}; then {wait})"


class ExampleFailure(AssertionError):
    """An example whose device behaviour the model does not allow: the steps and the finding."""

    def __init__(self, resource: str, start: str, steps: list[Step], failed_at: int, finding: Finding,
                 trace: list[str]) -> None:
        self.resource = resource
        self.start = start  # the observed state the example started from
        self.steps = steps
        self.failed_at = failed_at  # 1-based step; 0: before the first step
        self.finding = finding
        self.trace = trace
        super().__init__(self.describe())

    def describe(self) -> str:
        lines = [f"command sequence (from {self.start}):"]
        if not self.steps:
            lines.append("  (none: before the first command)")
        for i, step in enumerate(self.steps, start=1):
            mark = "   <- fails here" if i == self.failed_at else ""
            lines.append(f"  {i}. {step.describe(self.resource)}{mark}")
        lines.append(self.finding.describe())
        if self.trace:
            lines.append("observed (times from the start of the example):")
            lines += [f"  {line}" for line in self.trace[-20:]]
        return "\n".join(lines)


class SessionAborted(BaseException):
    """The test cannot go on (hub gone, another controller): not a finding, nothing to shrink.

    A BaseException, not an Exception: Hypothesis treats every Exception as a failure
    to shrink, and lets anything else through at once."""


@dataclass
class Session:
    link: ResourceLink
    oracle: ResourceOracle
    options: Options
    reset: Callable[[], None] | None = None
    say: Callable[[str], None] = print
    tainted: bool = False
    calls: int = 0
    passed: int = 0
    skipped: int = 0
    resets: int = 0
    first_failure_call: int = 0
    failures: list[ExampleFailure] = field(default_factory=list)
    checker: Checker | None = None
    _first_contact: bool = True

    # --- one example --------------------------------------------------------------------------
    def run_example(self, data: st.DataObject) -> None:
        self.calls += 1
        began = time.monotonic()
        steps: list[Step] = []
        failure: ExampleFailure | None = None
        start = "the state after commanding the initial values"
        try:
            if not self._prepare():
                self.skipped += 1
                return
            assert self.checker is not None and self.checker.last is not None
            start = self.oracle.describe(self.checker.last.measured, self.checker.last.env)
            count = data.draw(st.integers(1, self.options.max_steps))
            for _ in range(count):
                steps.append(self._draw_step(data))
                self._run_step(steps[-1])
            steps.append(Step(self._initial_command(), Wait.SETTLE, Source.HOME))  # every example ends at home, checked
            self._run_step(steps[-1])
        except Violation as exc:
            trace = self.checker.trace if self.checker is not None else []
            failure = ExampleFailure(self.oracle.resource.name, start, list(steps), len(steps), exc.finding,
                                     list(trace))
        self._progress(began, steps, failure)
        if failure is not None:
            self.tainted = True
            if not self.failures:
                self.first_failure_call = self.calls
            self.failures.append(failure)
            raise failure  # outside the except block: one origin for Hypothesis, whatever the finding
        self.passed += 1

    def _progress(self, began: float, steps: list[Step], failure: ExampleFailure | None) -> None:
        seconds = time.monotonic() - began
        shrinking = " (shrinking)" if self.failures else ""
        wanted = self.options.examples
        label = (f"run {self.calls}{shrinking}" if self.failures
                 else f"example {self.calls}/{wanted}" if self.calls <= wanted else f"example {self.calls} (extra)")
        result = "ok" if failure is None else f"FAILS at step {failure.failed_at}: {failure.finding.kind}"
        self.say(f"  {self.oracle.resource.name}: {label}: {len(steps)} commands, {result} ({seconds:.1f} s)")

    def _prepare(self) -> bool:
        """Bring the device to rest at the initial commands; False: tainted and cannot be restored."""
        if self.tainted and self.reset is not None:
            self.say(f"  {self.oracle.resource.name}: resetting the device (it failed; the next example must "
                     f"start where the model can be)")
            self.reset()
            self.resets += 1
            self.tainted = False
            self._first_contact = True
        start = self._home()
        reachable = self.oracle.is_reachable(start.measured)
        if self.tainted:
            if not reachable:
                return False
            self.tainted = False
        self.checker = Checker(self.oracle, self.options.deadline, self.options.sample_lag)
        self.checker.start(start)
        if not reachable:
            raise violation(Finding(
                FindingKind.START_STATE,
                f"after commanding the initial values the device rests at "
                f"{self.oracle.describe(start.measured)}, which the model cannot reach from its initial state "
                f"{self.oracle.describe(self.oracle.initial_measured)} by any commands",
                observed=self.oracle.describe(start.measured, start.env)))
        return True

    def _initial_command(self) -> dict[str, Value]:
        return {v.name: v.initial for v in self.oracle.resource.commands}

    def _home(self) -> Observation:
        """Command the initial values and wait (unchecked) until the device is at rest."""
        self.link.drain()
        seq = self.link.send(self._initial_command())
        timeout = self.options.startup_timeout if self._first_contact else self.options.deadline
        deadline = time.monotonic() + timeout
        last: Observation | None = None
        while last is None:
            sample = self.link.next_sample(deadline - time.monotonic())
            if sample is None:
                if self._first_contact:
                    raise SessionAborted(self._no_state(timeout))
                raise violation(Finding(FindingKind.MIRROR, f"the hub did not mirror the initial command (seq {seq}) "
                                                            f"within {timeout:g} s"))
            self._check_sample(sample, during_home=True)
            if sample.mirror_seq is not None and sample.mirror_seq >= seq \
                    and sample.mirror_controller == self.link.controller_id:
                last = self._observation(sample)
        self._first_contact = False
        limit = time.monotonic() + self.options.deadline * (self.options.max_effect_steps + 1)
        changed_at = time.monotonic()
        while time.monotonic() < limit:
            sample = self.link.next_sample(POLL_S)
            now = time.monotonic()
            if sample is not None:
                self._check_sample(sample, during_home=True)
                obs = self._observation(sample)
                if obs.key != last.key:
                    changed_at = now
                last = obs
            else:
                self._check_stale(now)
            at_rest = not any(self.oracle.observable(e, last.measured, last.env)
                              for e in self.oracle.enabled(last.measured, last.env))
            if at_rest and now - changed_at >= self.options.quiet:
                break
        return last

    # --- steps --------------------------------------------------------------------------------
    def _draw_step(self, data: st.DataObject) -> Step:
        assert self.checker is not None
        last = self.checker.latest
        candidates = self.oracle.model_commands(last.measured, last.env)
        pick = data.draw(st.integers(0, 3))
        if candidates and pick < self.options.model_share:
            command = candidates[data.draw(st.integers(0, len(candidates) - 1))]
            source = Source.MODEL
        else:
            command = data.draw(st.fixed_dictionaries(
                {v.name: st.sampled_from(v.domain.values) for v in self.oracle.resource.commands}))
            source = Source.ANY
        wait = data.draw(st.sampled_from(Wait))
        return Step(command, wait, source)

    def _run_step(self, step: Step) -> None:
        assert self.checker is not None
        sent_at = time.monotonic()
        seq = self.link.send(step.command)
        values = ", ".join(f"{k} := {format_value(v)}" for k, v in step.command.items())
        self.checker.note(sent_at, f"sent seq {seq}: {values}")
        checker = self.checker
        expected = {f"{self.oracle.resource.name}.{k}": v for k, v in step.command.items()}

        def mirrored(sample: StateSample | None) -> bool:
            if sample is None or sample.mirror_seq is None or sample.mirror_seq < seq:
                return False
            if sample.mirror_seq == seq and sample.mirror != expected:
                raise violation(Finding(FindingKind.MIRROR, f"the hub mirrors command seq {seq} as {sample.mirror}, "
                                                            f"but it was sent as {expected}",
                                        observed=checker.describe_last()))
            return True

        self._pump(mirrored, self.options.deadline, on_timeout=lambda: Finding(
            FindingKind.MIRROR,
            f"the hub did not mirror command seq {seq} ({values}) within {self.options.deadline:g} s",
            observed=checker.describe_last()))
        if step.wait is Wait.BRIEF:
            self._pump(lambda _sample: False, self.options.brief)
        else:
            self._settle()

    def _settle(self) -> None:
        """Wait until the model expects no change and nothing changed for `quiet` seconds."""
        checker = self.checker
        assert checker is not None
        limit = self.options.deadline * (self.options.max_effect_steps + 1) + self.options.quiet

        def at_rest(_sample: StateSample | None) -> bool:
            return checker.quiescent and time.monotonic() - checker.last_change >= self.options.quiet

        self._pump(at_rest, limit, check_idle=True)

    def _pump(self, done: Callable[[StateSample | None], bool], seconds: float, *,
              on_timeout: Callable[[], Finding] | None = None, check_idle: bool = False) -> None:
        """Feed every sample to the checker until `done(sample)` or `seconds` pass."""
        checker = self.checker
        assert checker is not None
        end = time.monotonic() + seconds
        while True:
            now = time.monotonic()
            if now >= end:
                if on_timeout is not None:
                    raise violation(on_timeout())
                return
            sample = self.link.next_sample(min(POLL_S, end - now))
            if sample is None:
                now = time.monotonic()
                self._check_stale(now)
                checker.check_time(now)
                if check_idle and done(None):
                    return
                continue
            self._check_sample(sample)
            checker.observe(self._observation(sample))
            if done(sample):
                return

    # --- samples ------------------------------------------------------------------------------
    def _observation(self, sample: StateSample) -> Observation:
        commands = sample.mirror or {}
        return Observation(sample.time, self.oracle.measured_of(sample.measured),
                           self.oracle.env_of(commands, sample.context))

    def _check_sample(self, sample: StateSample, *, during_home: bool = False) -> None:
        link = self.link
        if link.error is not None:
            raise SessionAborted(f"cannot test {link.resource.name}: {link.error}")
        foreign = sample.mirror_controller
        if foreign is not None and foreign != link.controller_id and sample.mirror_seq is not None \
                and not during_home:
            raise SessionAborted(self._foreign_message(foreign))
        if link.foreign:
            raise SessionAborted(self._foreign_message(next(iter(link.foreign))))
        ours = sample.mirror_controller == link.controller_id
        if during_home and not ours:
            return  # not yet under our command: whatever state the hub is in
        if sample.status is not HubStatus.OK:
            raise violation(Finding(FindingKind.HUB_STATUS, f"hub {sample.hub} reports {sample.status.value} for "
                                                f"{link.resource.name}: {sample.detail or '(no detail)'}",
                                    observed=self._describe_sample(sample)))
        unknown = [p for p, v in sample.measured.items() if v is None]
        if unknown:
            raise violation(Finding(FindingKind.HUB_STATUS, f"hub {sample.hub} reports {', '.join(unknown)} unknown",
                                    observed=self._describe_sample(sample)))

    def _describe_sample(self, sample: StateSample) -> str:
        values = {**(sample.mirror or {}), **sample.measured}
        return ", ".join(f"{p}={'unknown' if v is None else format_value(v)}" for p, v in values.items())

    def _check_stale(self, now: float) -> None:
        last = self.link.last_sample_at
        if last is not None and now - last > self.options.stale_after:
            raise SessionAborted(f"no state of {self.link.resource.name} for {now - last:.1f} s: "
                                 f"the hub is gone (stopped, crashed or unreachable)")

    def _foreign_message(self, controller: str) -> str:
        name = self.link.resource.name
        return (f"another controller ({controller}) is commanding {name} on {self.link.keys.cmd(name)}: "
                f"stop it first; two controllers would fight over the hub")

    def _no_state(self, timeout: float) -> str:
        name = self.link.resource.name
        return (f"no state of {name} on {self.link.keys.state(name)} within {timeout:g} s: is its hub running "
                f"and connected to this process's zenoh endpoints?")

