"""The commands the controller sends: per resource the command values last sent and their `seq`.

The one owner of `seq`. A resource's command carries a new seq whenever its values differ from those it
was last sent (its first command has seq 0), so that the mirror-watchdog sees a new command applied; the
same values go out again, under the same seq, at the command rate, so that a hub that restarted or
missed one catches up at once. Nothing goes to a held resource (controller/command_hold.py): its command state
is unknown, and the model's initial values in its place could be far from what the station is doing.

The outbox decides what is sent and under which seq; its shell (the controller service, or a runner in
virtual time) publishes the messages, or only records them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from common.model import Value
from common.model.compiled import State


@dataclass(frozen=True)
class CommandVariable:
    name: str  # in the resource's command message
    path: str  # in the global state
    index: int  # in the state tuple


@dataclass(frozen=True)
class Command:
    """One command message to send: `values` by variable name, under `seq`; `changed` when the values
    differ from those the resource was sent before (a new seq, or its first command)."""

    resource: str
    values: dict[str, Value]
    seq: int
    changed: bool


class Outbox:
    def __init__(self, variables: Mapping[str, Sequence[CommandVariable]]) -> None:
        """`variables`: the command variables of each resource the controller commands, in sending order."""
        self.variables = {resource: tuple(vs) for resource, vs in variables.items() if vs}
        self._seq = dict.fromkeys(self.variables, 0)
        self._sent: dict[str, tuple[Value, ...]] = {}  # the values each resource was last sent, under its seq

    def changed(self, state: State, held: frozenset[str]) -> list[Command]:
        """The commands whose values differ from those last sent (a force or a mirror taken between two
        ticks is a change too: against what was sent, not the tick's start)."""
        commands = []
        for resource, variables in self.variables.items():
            if resource not in held and self._sent.get(resource) != tuple(state[v.index] for v in variables):
                commands.append(self._take(resource, state))
        return commands

    def every(self, state: State, held: frozenset[str], resources: Iterable[str] | None = None) -> list[Command]:
        """The command of every resource (of `resources`, if given) but the held ones: the periodic resend,
        a new seq where values changed since they were last sent. Sent to unhealthy resources too: the
        engine changes nothing for them, and the same state again lets a recovering hub catch up at once."""
        chosen = self.variables if resources is None else resources
        return [self._take(resource, state) for resource in chosen if resource not in held]

    def highest_seq(self, resource: str) -> int:
        """The highest seq `resource` may have been sent: 0 before its first command, -1 if the controller
        never commands it (a mirror in its name with a higher seq was forged)."""
        return self._seq.get(resource, -1)

    def _take(self, resource: str, state: State) -> Command:
        variables = self.variables[resource]
        current, previous = tuple(state[v.index] for v in variables), self._sent.get(resource)
        if previous is not None and previous != current:
            self._seq[resource] += 1
        self._sent[resource] = current
        values = {v.name: value for v, value in zip(variables, current, strict=True)}
        return Command(resource, values, self._seq[resource], changed=previous != current)
