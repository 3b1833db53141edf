"""The go-to ability template shared by devices that travel between named positions (lift, MiR, AGV).

The command holds the target; the measured position passes through one intermediate
value (`between`, `moving`) on the way, so travel is two effects: leave, then arrive.
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import Ability, Phase, Value, Variable, ability


def goto_abilities(prefix: str, command: Variable, position: Variable, targets: Mapping[str, str],
                   moving: str) -> tuple[Ability, ...]:
    """One ability per target command value: `{prefix}_{target}`.

    `targets` maps each command value to the position it brings the device to.
    Re-targeting while on the way is allowed (a lift reverses, a MiR re-routes),
    so `enabled` only asks that the device is not already sent to, or at, the target.
    """
    return tuple(_goto(f"{prefix}_{target}", command, position, target, arrived, moving)
                 for target, arrived in targets.items())


def _goto(name: str, command: Variable, position: Variable, target: str, arrived: str, moving: str) -> Ability:
    departures: tuple[Value, ...] = tuple(p for p in position.domain.values if p not in (arrived, moving))
    sent = command == target
    leaving = position == departures[0] if len(departures) == 1 else position.is_in(*departures)
    return ability(
        name,
        enabled=Phase((command != target) & (position != arrived), deliberate=f"{command.path} := {target}"),
        starting=Phase(sent & leaving, effects=[f"{position.path} := {moving}"]),
        executing=Phase(sent & (position == moving), effects=[f"{position.path} := {arrived}"]),
        finished=sent & (position == arrived),
    )
