"""The mirror-watchdog: is each resource's hub alive, fresh, and applying the commands it is sent?

A resource is unhealthy when its hub's liveliness token is gone, its state is older
than `stale_after`, its hub reports a problem (device lost, safe state, rejected
command), or its mirror lags the newest command for longer than `mirror_bound`.
Pure logic with an injectable clock; the controller process feeds it events.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

HEALTHY_STATUSES = frozenset({"ok", "no_command"})


@dataclass
class ResourceWatch:
    resource: str
    hub: str
    alive: bool = False
    last_state: float | None = None
    hub_status: str = "unknown"
    hub_detail: str = ""
    commanded_seq: int = 0
    commanded_at: float | None = None
    mirrored_seq: int = -1
    ever_seen: bool = False


@dataclass(frozen=True)
class Health:
    resource: str
    hub: str
    healthy: bool
    reason: str
    age: float | None  # seconds since the last state
    mirror_lag: int  # commands not yet mirrored


class Watchdog:
    def __init__(self, hubs_of: Mapping[str, str], *, stale_after: float = 0.5, mirror_bound: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.watches = {r: ResourceWatch(r, h) for r, h in hubs_of.items()}
        self.stale_after = stale_after
        self.mirror_bound = mirror_bound
        self.clock = clock

    def hub_alive(self, hub: str, alive: bool) -> None:
        for w in self.watches.values():
            if w.hub == hub:
                w.alive = alive

    def state_received(self, resource: str, status: str, detail: str, mirrored_seq: int | None) -> None:
        w = self.watches.get(resource)
        if w is None:
            return
        w.last_state = self.clock()
        w.ever_seen = True
        w.hub_status, w.hub_detail = status, detail
        if mirrored_seq is not None:
            w.mirrored_seq = mirrored_seq

    def command_sent(self, resource: str, seq: int) -> None:
        w = self.watches[resource]
        if seq != w.commanded_seq:
            w.commanded_seq = seq
            w.commanded_at = self.clock()

    def reset_mirror(self, resource: str) -> None:
        """A new controller run: earlier mirrors say nothing about our commands."""
        self.watches[resource].mirrored_seq = -1

    def health(self, resource: str) -> Health:
        w = self.watches[resource]
        now = self.clock()
        age = None if w.last_state is None else now - w.last_state
        lag = max(0, w.commanded_seq - w.mirrored_seq) if w.commanded_at is not None else 0
        reason = ""
        if not w.alive:
            reason = f"hub {w.hub} is not alive (no liveliness token)"
        elif age is None:
            reason = f"no state received from hub {w.hub} yet"
        elif age > self.stale_after:
            reason = f"state is stale: last one {age:.2f} s ago (bound {self.stale_after} s)"
        elif w.hub_status not in HEALTHY_STATUSES:
            reason = f"hub reports {w.hub_status}" + (f": {w.hub_detail}" if w.hub_detail else "")
        elif lag and w.commanded_at is not None and now - w.commanded_at > self.mirror_bound:
            reason = (f"mirror lags: command seq {w.commanded_seq} sent {now - w.commanded_at:.2f} s ago, "
                      f"hub mirrors seq {w.mirrored_seq}")
        return Health(resource, w.hub, not reason, reason, age, lag)

    def unhealthy(self) -> dict[str, str]:
        result = {}
        for resource in self.watches:
            h = self.health(resource)
            if not h.healthy:
                result[resource] = h.reason
        return result
