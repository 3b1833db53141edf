"""The model-driven emulator: the physical device is its resource's effect transitions.

An enabled effect fires after a time within its duration interval (the station's
`DurationTable`, common/model/durations.py), picked with a seeded random and scaled by
`speed`; an effect with several outcomes picks one with the same random, so a nutrunner
that fails with probability p is `failure={"nr": p}`. The emulator keeps no control
state: it reads the command values it is given and writes measured values only.
"""

from __future__ import annotations

import random
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass

from common.model import Duration, DurationTable, Model, Transition, TransitionKind, Value, apply_all
from common.model.compiled import compile_predicate
from common.model.durations import as_duration, effect_owner
from common.resources import durations_of


@dataclass
class _Scheduled:
    due: float
    outcome: int


class EffectEmulator:
    def __init__(
        self,
        model: Model,
        resources: Iterable[str],
        *,
        speed: float = 1.0,
        seed: int = 0,
        failure: Mapping[str, float] | None = None,
        delays: Mapping[str, Duration | float] | None = None,
    ) -> None:
        """`delays`: hubs.toml's `delay` by resource (seconds, or an interval), over the model's durations."""
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        self.model = model
        self.resources = frozenset(resources)
        unknown = self.resources - set(model.resource_by_name)
        if unknown:
            raise KeyError(f"model {model.name!r} has no resource {', '.join(sorted(unknown))}")
        self.effects: tuple[Transition, ...] = tuple(
            t for t in model.ability_transitions
            if t.kind is TransitionKind.EFFECT and t.written() and self._owners(t) <= self.resources
        )
        self.speed = speed
        self.random = random.Random(seed)
        self.failure = dict(failure or {})
        self.durations: DurationTable = durations_of(model, {r: as_duration(d) for r, d in (delays or {}).items()})
        self._intervals: dict[str, Duration] = {}  # effect -> its interval at this speed
        self.pending: dict[str, _Scheduled] = {}
        self.paths = frozenset(p for t in self.effects for p in t.guard.paths() | t.written())
        # The guards compiled over the tuple of the values they read (`_read`): a station in virtual time steps
        # the emulator at every change, and judging each guard's predicate tree was a fifth of such a run.
        self._reads = tuple(sorted({p for t in self.effects for p in t.guard.paths()}))
        position = {path: i for i, path in enumerate(self._reads)}
        self._guards = tuple(compile_predicate(t.guard, position) for t in self.effects)

    @staticmethod
    def _owners(t: Transition) -> set[str]:
        return {p.split(".", 1)[0] for p in t.written()}

    def delay_of(self, t: Transition) -> float:
        """How long this occurrence of effect `t` takes: a time within its interval at this speed."""
        interval = self._intervals.get(t.name)
        if interval is None:
            interval = self._intervals[t.name] = self.durations.of_transition(t).scaled(self.speed)
        return interval.pick(self.random)

    def _choose(self, t: Transition) -> int:
        if len(t.outcomes) == 1:
            return 0
        p_fail = self.failure.get(effect_owner(t), 0.0)
        if self.random.random() >= p_fail:
            return 0  # the first outcome is the nominal one (torque reached)
        return self.random.randrange(1, len(t.outcomes))

    def step(self, state: Mapping[str, Value], now: float, hold: Collection[str] = ()) -> dict[str, Value]:
        """Schedule newly enabled effects, fire the due ones except those named in `hold` (they stay
        scheduled); returns the measured values that changed."""
        changes: dict[str, Value] = {}
        current = dict(state)
        read = self._read(current)
        for t, guard in zip(self.effects, self._guards, strict=True):
            enabled = guard(read)
            scheduled = self.pending.get(t.name)
            if not enabled:
                self.pending.pop(t.name, None)
                continue
            if scheduled is None:
                self.pending[t.name] = _Scheduled(now + self.delay_of(t), self._choose(t))
            elif scheduled.due <= now and t.name not in hold:
                del self.pending[t.name]
                after = apply_all(t.outcomes[scheduled.outcome], current)
                for path in t.written():
                    if after[path] != current[path]:
                        changes[path] = after[path]
                current = after
                read = self._read(current)
        return changes

    def _read(self, values: Mapping[str, Value]) -> tuple[Value, ...]:
        return tuple(values[path] for path in self._reads)

    def next_due(self, hold: Collection[str] = ()) -> float | None:
        return min((s.due for name, s in self.pending.items() if name not in hold), default=None)
