"""Timing hazards of a station model, named before a run (`hubctl check`).

Plans are sequences in which an enabled effect waits for the plan; on the station it happens
within its duration whatever the plan does next (DESIGN.md §4). Three shapes of model let a
command or another effect take an effect's condition away first:

* SENSED_DEVICE_MOVES: an effect whose guard reads another device's measured values that the
  controller's commands change (issue 21: the feeder's "box taken" sensor needs the robot at the
  feeder, and a command sends the robot on). Found: from a state where the effect is due, a command
  starts the other device's effects (one, or two in a row: a move leaves, then arrives), the effect
  still due after each, and the last of them makes its guard false.
* COMMAND_DISABLES_EFFECT: a deliberate command whose own actions make a due effect's guard false.
* TRACKING_NEEDS_TRANSIENT: tracking (automatic, writing estimated variables) enabled by a measured
  value that another effect, already enabled when the value appears, changes again: the value lasts
  only that effect's duration, and a controller that does not see it in time never records it.

Each is decided on the model's guards (and the supervisor's, when given) over the variables'
domains, not over reachable states: a warning may name a state the station never enters, never
misses one the guards allow (`common/model/satisfiable.py`; a search that runs out of budget counts
as possible). Pure: model, durations and guards in, warnings out.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

from common.model import (
    TRUE,
    Duration,
    DurationTable,
    Kind,
    Model,
    Not,
    Predicate,
    Transition,
    TransitionKind,
    all_of,
)
from common.model.durations import effect_owner
from common.model.rewrite import after
from common.model.satisfiable import satisfiable

MOVE_EFFECTS_FOLLOWED = 2  # a command's effects followed in a row: a move leaves a pose, then arrives
NAMES_SHOWN = 6  # transitions named in a warning's text before "and N more"


class HazardKind(Enum):
    SENSED_DEVICE_MOVES = "an effect reads another device that commands change"
    COMMAND_DISABLES_EFFECT = "a command disables an effect that is due"
    TRACKING_NEEDS_TRANSIENT = "tracking needs a value that lasts only an effect's duration"


@dataclass(frozen=True)
class TimingHazard:
    kind: HazardKind
    subject: str  # the effect at risk, or the tracking transition
    variable: str  # the measured variable through which it happens ("" when a command writes the guard's own)
    transitions: tuple[str, ...]  # the commands (or, for tracking, the effects) that take its condition away
    text: str  # what happens, with the durations
    remedy: str  # what would make the model safe

    def __str__(self) -> str:
        return f"{self.text}\n    safe if: {self.remedy}"


def timing_hazards(model: Model, durations: DurationTable,
                   extra_guards: Mapping[str, Predicate] | None = None) -> list[TimingHazard]:
    """Every timing hazard of `model`; `extra_guards`: the supervisor's synthesized guards by transition."""
    return _Analysis(model, durations, extra_guards or {}).run()


class _Analysis:
    def __init__(self, model: Model, durations: DurationTable, extra_guards: Mapping[str, Predicate]) -> None:
        self.model = model
        self.durations = durations
        self.extra_guards = extra_guards
        self.domains = {path: v.domain for path, v in model.variables.items()}
        transitions = model.ability_transitions
        self.effects = tuple(t for t in transitions if t.kind is TransitionKind.EFFECT and t.written())
        self.commands = tuple(t for t in transitions if t.kind is not TransitionKind.EFFECT
                              and any(model.var(p).kind is Kind.COMMAND for p in t.written()))
        self.deliberate = tuple(t for t in transitions if t.kind is TransitionKind.DELIBERATE)
        self.tracking = tuple(t for t in transitions if t.kind is TransitionKind.AUTOMATIC
                              and any(model.var(p).kind is Kind.ESTIMATED for p in t.written()))
        self._chains: dict[tuple[str, str], tuple[tuple[Transition, ...], ...]] = {}
        self.effects_of: dict[str, list[Transition]] = defaultdict(list)
        for e in self.effects:
            self.effects_of[effect_owner(e)].append(e)

    def run(self) -> list[TimingHazard]:
        return [*self.sensed_device_moves(), *self.commands_disabling_effects(), *self.transient_tracking()]

    # --- helpers ---------------------------------------------------------------------------------
    def possible(self, *conditions: object) -> bool:
        return satisfiable(all_of(*conditions), self.domains).possible

    def possible_when_given(self, command: Transition, *conditions: object) -> bool:
        """The conditions can hold while the engine would fire `command` (its own guard and the supervisor's).
        The supervisor's guards are large: they are asked only once the model's guard leaves it possible."""
        if not self.possible(*conditions, command.guard):
            return False
        extra = self.extra_guards.get(command.name)
        return extra is None or self.possible(*conditions, command.guard, extra)

    def duration(self, effect: Transition) -> Duration:
        return self.durations.of_transition(effect)

    def measured_of_others(self, effect: Transition) -> list[str]:
        owner = effect_owner(effect)
        return sorted(p for p in effect.guard.paths()
                      if self.model.var(p).kind is Kind.MEASURED and p.split(".", 1)[0] != owner)

    # --- (a) an effect reads another device that commands change --------------------------------
    def sensed_device_moves(self) -> Iterable[TimingHazard]:
        for e in self.effects:
            for path in self.measured_of_others(e):
                device = path.split(".", 1)[0]
                device_commands = {v.path for v in self.model.resource_by_name[device].commands}
                found: dict[str, tuple[Transition, ...]] = {}  # command -> the device's effects that break e
                for command in self.commands:
                    if command.written() & device_commands:
                        chain = self._breaking_chain(e, path, command, device)
                        if chain:
                            found[command.name] = chain
                if found:
                    yield self._sensed_warning(e, path, device, found)

    def _breaking_chain(self, e: Transition, path: str, command: Transition, device: str) -> tuple[Transition, ...]:
        """The quickest of the device's effect chains that `command` starts from a state where `e` is due
        and whose last effect takes `e`'s condition away through `path`; () when none can."""
        breaking = [chain for chain in self._started_chains(command, device)
                    if path in chain[-1].written() and self._chain_possible(e.guard, command, chain, breaks=True)]
        return min(breaking, key=self._soonest, default=())

    def _started_chains(self, command: Transition, device: str) -> tuple[tuple[Transition, ...], ...]:
        """The device's effects that `command` can set going, one after the other (whatever is due
        elsewhere): each chain is one the command enables first and the next that follows."""
        key = (command.name, device)
        known = self._chains.get(key)
        if known is not None:
            return known
        chains: list[tuple[Transition, ...]] = []

        def extend(chain: tuple[Transition, ...]) -> None:
            # An effect the command (or the chain so far) cannot have enabled is not its consequence.
            written = command.written().union(*(f.written() for f in chain))
            for f in self.effects_of[device]:
                if f in chain or not f.guard.paths() & written:
                    continue
                longer = (*chain, f)
                if self._chain_possible(TRUE, command, longer, breaks=False):
                    chains.append(longer)
                    if len(longer) < MOVE_EFFECTS_FOLLOWED:
                        extend(longer)

        extend(())
        self._chains[key] = tuple(chains)
        return self._chains[key]

    def _soonest(self, chain: Sequence[Transition]) -> float:
        return sum(self.duration(f).min_s for f in chain)

    def _chain_possible(self, due: Predicate, command: Transition, chain: tuple[Transition, ...],
                        *, breaks: bool) -> bool:
        """A state where `due` holds and `command` may fire, after which the chain's effects fire one
        after the other, each enabled when its turn comes (the first only by the command), `due` holding
        all along; with `breaks`, the last effect's outcome makes `due` false."""
        last = chain[-1]
        for outcome in last.outcomes:
            # Built backwards: the condition on the state after each step, rewritten into the one before.
            condition: Predicate = Not(after(due, outcome)) if breaks else after(due, outcome)
            condition = all_of(due, last.guard, condition)
            for f in reversed(chain[:-1]):
                condition = all_of(due, f.guard, after(condition, f.outcomes[0]))
            # What the command's actions decide goes first: it is the part most often false at once.
            if self.possible_when_given(command, after(condition, command.actions), due, Not(chain[0].guard)):
                return True
        return False

    def _sensed_warning(self, e: Transition, path: str, device: str,
                        found: Mapping[str, tuple[Transition, ...]]) -> TimingHazard:
        owner = effect_owner(e)
        own = self.duration(e)
        # The soonest the condition goes: the quickest chain, each of its effects at its shortest.
        quickest = min(found.values(), key=self._soonest)
        gone_after = self._soonest(quickest)
        race = (f"the command wins the race: {owner}'s effect takes up to {own.max_s:g} s, {path} changes "
                f"{gone_after:g} s after the command ({' then '.join(f.name for f in quickest)})"
                if own.max_s >= gone_after else
                f"the durations keep it safe, by timing only: {owner}'s effect takes at most {own.max_s:g} s, "
                f"{path} changes {gone_after:g} s after the command at the soonest")
        commands = tuple(sorted(found))
        text = (f"{e.name} ({_outcomes(e)}) reads {path}, which commands can change while it is due: "
                f"{_names(commands)}; {race}")
        remedy = (f"guard those commands with {e.name}'s result ({_outcomes(e)}), or keep {owner}'s duration "
                  f"(now {own}) below the {gone_after:g} s {device} takes to change {path}")
        return TimingHazard(HazardKind.SENSED_DEVICE_MOVES, e.name, path, commands, text, remedy)

    # --- (b) a command disables an effect that is due -------------------------------------------
    def commands_disabling_effects(self) -> Iterable[TimingHazard]:
        for e in self.effects:
            reads = e.guard.paths()
            disabling = tuple(
                command.name for command in self.deliberate
                if command.written() & reads
                and self.possible_when_given(command, e.guard, Not(after(e.guard, command.actions)))
            )
            if disabling:
                owner = effect_owner(e)
                text = (f"{e.name} ({_outcomes(e)}, {self.duration(e)}) is disabled by {_names(disabling)} "
                        f"if given while it is due")
                remedy = (f"guard those commands with {e.name}'s result ({_outcomes(e)}), or make them wait "
                          f"until {owner} is done (a plan must not count on the effect after them)")
                yield TimingHazard(HazardKind.COMMAND_DISABLES_EFFECT, e.name, "", disabling, text, remedy)

    # --- (c) tracking that needs a transient value ----------------------------------------------
    def transient_tracking(self) -> Iterable[TimingHazard]:
        for track in self.tracking:
            measured = {p for p in track.guard.paths() if self.model.var(p).kind is Kind.MEASURED}
            for path in sorted(measured):
                writers = [e for e in self.effects if path in e.written()]
                # Cheap necessary conditions first: `sets` can enable the tracking, `resets` can disable it.
                setters = [e for e in writers
                           if any(self.possible(after(track.guard, o), e.guard) for o in e.outcomes)]
                resetters = [e for e in writers
                             if any(self.possible(Not(after(track.guard, o)), track.guard, e.guard)
                                    for o in e.outcomes)]
                pairs = [(sets, resets) for sets in setters for resets in resetters
                         if self._transient(track, sets, resets)]
                if pairs:
                    yield self._transient_warning(track, path, pairs)

    def _transient(self, track: Transition, sets: Transition, resets: Transition) -> bool:
        """Right after `sets` fires, `track` is enabled and `resets` already is, and would disable it.
        Before, the controller had settled: no automatic transition that commands the resetting device
        was pending (it fires at once, so a state with one enabled does not last)."""
        settled = [Not(a.guard) for a in self._commanding(effect_owner(resets))]
        for set_outcome in sets.outcomes:
            for reset_outcome in resets.outcomes:
                then = all_of(track.guard, resets.guard, Not(after(track.guard, reset_outcome)))
                if self.possible(after(then, set_outcome), sets.guard, *settled):
                    return True
        return False

    def _commanding(self, device: str) -> list[Transition]:
        """The automatic transitions that write the device's commands."""
        commands = {v.path for v in self.model.resource_by_name[device].commands}
        return [t for t in self.commands if t.kind is TransitionKind.AUTOMATIC and t.written() & commands]

    def _transient_warning(self, track: Transition, path: str,
                           pairs: Sequence[tuple[Transition, Transition]]) -> TimingHazard:
        shortest = min(pairs, key=lambda pair: self.duration(pair[1]).min_s)
        lasts = self.duration(shortest[1])
        effects = tuple(dict.fromkeys(name for pair in pairs for name in (pair[0].name, pair[1].name)))
        text = (f"{track.name} needs {path} as {shortest[0].name} sets it, but {shortest[1].name} changes it "
                f"again without a command, {lasts} later: the controller must see it within {lasts.min_s:g} s")
        remedy = (f"have the device hold {path} until a command resets it (a latch the controller "
                  f"acknowledges), or let {track.name} read a value that lasts")
        return TimingHazard(HazardKind.TRACKING_NEEDS_TRANSIENT, track.name, path, effects, text, remedy)


def _outcomes(effect: Transition) -> str:
    return " or ".join("; ".join(str(a) for a in outcome) for outcome in effect.outcomes)


def _names(names: Sequence[str]) -> str:
    shown = ", ".join(names[:NAMES_SHOWN])
    return shown + (f" and {len(names) - NAMES_SHOWN} more" if len(names) > NAMES_SHOWN else "")

