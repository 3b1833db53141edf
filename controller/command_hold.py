"""Resources whose command state a restarted controller does not know: held until their mirror arrives.

A restarted controller takes each resource's command state from the mirror its hub publishes (the
command it applied last). A resource whose mirror has not come within the start-up wait is held: it is
sent no command, its command variables are unknown to the control core (no transition, operation start
or specification reads them: `ControlCore.set_unknown`) and it is disabled for the engine and the
planner. The model's initial values, which may be far from what the station is doing (`rsp.lock_c =
false` while the robot holds a tool away from the dock), are not sent in its place. When its mirror
arrives, its command state is taken from it and the hold ends.

A hub that restarted too reports that it has no command (its devices in their safe state), at start or
later: the model's initial values are then its command state, as at a first start, but only if they
make no specification hold in the current state; otherwise the resource stays held, and this is logged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

from common.model import Value
from common.wire.ctl import HoldReleased, MirrorsMissing
from common.wire.messages import HubStatus
from controller.control import ControlCore

log = logging.getLogger("statehub.controller.hold")


class CommandHold:
    def __init__(self, core: ControlCore, commands: Mapping[str, Sequence[str]], hubs_of: Mapping[str, str]) -> None:
        """`commands`: each commanded resource's command variables (their names); `hubs_of`: its hub."""
        self.core = core
        self.paths = {r: [f"{r}.{name}" for name in names] for r, names in commands.items()}
        self.hubs_of = hubs_of
        self.held: frozenset[str] = frozenset()
        self._refusal_said: set[str] = set()

    def start(self, mirrors: Mapping[str, Mapping[str, Value]], waited_s: float) -> None:
        """At the end of the start-up wait: take every mirror's command state, hold the resources without one.
        `mirrors[r]` is empty when r's hub reported that it has no command (or r takes no command)."""
        taken = {path: value for r, values in mirrors.items() for path, value in self._prefixed(r, values).items()}
        if taken:
            self.core.load(taken)
            log.info("took the command state of %d resources from their mirrors", sum(map(bool, mirrors.values())))
        missing = sorted(set(self.paths) - set(mirrors))
        self._set_held(missing)
        for resource, values in mirrors.items():
            if resource in self.paths and not values and not self._initial_values_safe(resource):
                self._set_held([*self.held, resource])
        if missing:
            by_hub: dict[str, list[str]] = {}
            for r in missing:
                by_hub.setdefault(self.hubs_of[r], []).append(r)
            event = MirrorsMissing(by_hub)
            log.warning("no mirror within %.1f s from %s: held, sent no command until their mirrors arrive",
                        waited_s, event.report)
            self.core.events.log.emit(event)

    def arrived(self, resource: str, mirror: Mapping[str, Value] | None, status: str) -> None:
        """A held resource's state came: its mirror's values (None if it has none) and its hub's status."""
        if mirror is not None:
            self.core.load(self._prefixed(resource, mirror))
            self._release(resource, "its mirror")
        elif status == HubStatus.NO_COMMAND and self._initial_values_safe(resource):
            initial = self.core.compiled.initial()
            index = self.core.compiled.index
            self.core.load({path: initial[index[path]] for path in self.paths[resource]})
            self._release(resource, "the model's initial values (its hub has no command)")

    def _prefixed(self, resource: str, values: Mapping[str, Value]) -> dict[str, Value]:
        return {f"{resource}.{name}": value for name, value in values.items()}

    def _release(self, resource: str, source: str) -> None:
        self._set_held(self.held - {resource})
        event = HoldReleased(resource, source)
        log.info("%s", event.text)
        self.core.events.log.emit(event)

    def _set_held(self, resources: Sequence[str] | frozenset[str]) -> None:
        self.held = frozenset(resources)
        self.core.set_unknown(path for r in self.held for path in self.paths[r])

    def _initial_values_safe(self, resource: str) -> bool:
        """The model's initial command values of `resource` make no specification hold in the current state."""
        compiled = self.core.compiled
        mine = frozenset(compiled.index[p] for p in self.paths[resource])
        initial = compiled.initial()
        state = compiled.with_values(self.core.state, {compiled.paths[i]: initial[i] for i in mine})
        unknown = self.core.unknown - mine
        violations = self.core.safety.violations(state, unknown, reading=mine)
        if violations and resource not in self._refusal_said:
            self._refusal_said.add(resource)
            log.warning("%s (hub %s) has no command and its initial values would make specification %s hold: "
                        "held, sent no command", resource, self.hubs_of[resource],
                        "; ".join(v.describe() for v in violations))
        return not violations
