"""The run's longest causal chain: how soon its work could have ended had nothing waited but for causes.

Each variable keeps when, at the earliest, it could have got its present value. A transition seen happen
starts when every variable its model guard and actions read had theirs, and ends its duration later (an
effect) or at once (the controller's own); what it writes gets that end. A transition seen happen later
than that waited for something outside the chain: a resource busy elsewhere, a specification, a plan.

What happened comes from the two places the controller sees it: the transitions its engine fired
(commands, automatic transitions, operations' starts and finishes: `TickResult.fired`), and the measured
changes, each explained by the effects whose guard held and whose outcome wrote the new values. The
supervisor's synthesized guards are left out: which of two steps a specification lets go first is a
choice, not a cause. A change no effect explains (a restarted hub, a value forced) starts no chain: the
bound only gets weaker, never wrong.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from common.model import TransitionKind
from common.model.compiled import CompiledModel, CompiledTransition, State

from .exclusions import RunLog

MAX_EFFECTS_PER_CHANGE = 64  # effects explained in one batch of measured values: a bound, never reached


class CausalChain:
    def __init__(self, compiled: CompiledModel, seconds: Mapping[str, float], log: RunLog | None = None) -> None:
        """`seconds`: each effect's duration by transition name (controller/cycle.py's `effect_seconds`); `log`:
        where each transition seen happen is also kept, for the bound from the specifications' exclusions
        (controller/exclusions.py)."""
        self.compiled = compiled
        self.log = log
        self.seconds = seconds
        self.ready: dict[int, float] = {}  # variable index -> when, in the chain, it got its present value
        self.longest = 0.0
        index = compiled.index
        self._reads = {t.name: frozenset(index[p] for p in t.source.read()) for t in compiled.transitions}
        self._writing: dict[int, list[CompiledTransition]] = {}
        for effect in compiled.effects:
            for i in effect.writes:
                self._writing.setdefault(i, []).append(effect)

    def fired(self, names: Iterable[str]) -> None:
        """The controller's own transitions, in the order the engine fired them: they take no time."""
        for name in names:
            transition = self.compiled.by_name.get(name)
            if transition is not None and transition.kind is not TransitionKind.EFFECT:
                self._happened(transition, 0.0, transition.writes)
                if self.log is not None:
                    self.log.fired(transition)

    def measured(self, before: State, after: State, changed: Iterable[str] | None = None) -> None:
        """Measured values went from `before` to `after` (`changed`: the paths that did, if known): the effects
        that explain it, one after another."""
        state = before
        if self.log is not None and tuple(self.log.state) != tuple(before):
            # What the log has not seen change (a value forced between two measurements) changed by itself.
            self.log.unexplained(before, [i for i, v in enumerate(before) if self.log.state[i] != v])
        candidates = (range(len(after)) if changed is None
                      else [self.compiled.index[p] for p in changed if p in self.compiled.index])
        for _ in range(MAX_EFFECTS_PER_CHANGE):
            differing = [i for i in candidates if state[i] != after[i]]
            if not differing:
                return
            explained = self._explaining(state, after, differing)
            if explained is None:
                for i in differing:  # nothing explains it: it starts no chain
                    self.ready.pop(i, None)
                if self.log is not None:
                    self.log.unexplained(after, differing)
                return
            effect, moved = explained
            self._happened(effect, self.seconds.get(effect.name, 0.0),
                           [i for i in effect.writes if moved[i] != state[i]])
            if self.log is not None:
                self.log.effect(effect, moved)
            state = moved

    def _explaining(self, state: State, after: State,
                    differing: list[int]) -> tuple[CompiledTransition, State] | None:
        """An effect enabled in `state` with an outcome that writes only values `after` has, at least one of
        them new, and the state that outcome makes; of several, the one whose chain starts first (the bound
        stays a bound)."""
        best: tuple[CompiledTransition, State] | None = None
        best_start = 0.0
        seen: set[str] = set()
        for i in differing:
            for effect in self._writing.get(i, ()):
                if effect.name in seen:
                    continue
                seen.add(effect.name)
                if not effect.guard(state):
                    continue
                moved = next((m for m in (o(state) for o in effect.outcomes)
                              if self._moves_towards(m, state, after, effect.writes)), None)
                if moved is None:
                    continue
                start = self._start(effect)
                if best is None or start < best_start:
                    best, best_start = (effect, moved), start
        return best

    @staticmethod
    def _moves_towards(outcome: State, state: State, after: State, writes: frozenset[int]) -> bool:
        changed = [i for i in writes if outcome[i] != state[i]]
        return bool(changed) and all(outcome[i] == after[i] for i in changed)

    def _start(self, transition: CompiledTransition) -> float:
        return max((self.ready.get(i, 0.0) for i in self._reads[transition.name]), default=0.0)

    def _happened(self, transition: CompiledTransition, seconds: float, written: Iterable[int]) -> None:
        end = self._start(transition) + seconds
        for i in written:
            self.ready[i] = end
        self.longest = max(self.longest, end)
