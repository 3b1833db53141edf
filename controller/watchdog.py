"""The mirror-watchdog: is each resource's hub alive, fresh, and applying the commands it is sent?

A resource is unhealthy when its hub's liveliness token is gone, its state is older
than `stale_after`, its hub reports a problem (device lost, safe state, rejected
command), or a command it was sent is not mirrored within `mirror_bound` (measured from when
the oldest command the mirror does not cover yet was first sent, so that a hub that applies
nothing is reported even while the commands keep changing).

A `rejected` status names the hub's newest refused command, whoever sent it, and stays
until the hub applies a valid one. It may concern this controller only if it appeared
after the oldest of our commands the hub has not mirrored yet was sent; otherwise it was
another controller's command (or garbage), of which the hub applied nothing: the resource
stays healthy and the rejection is only reported (`Health.note`).

Pure logic with an injectable clock; the controller process feeds it events.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from common.wire.messages import HubStatus

# A hub reports nothing wrong: it applies our commands, or has had none yet (its outputs in the safe state).
HEALTHY_STATUSES = frozenset({HubStatus.OK, HubStatus.NO_COMMAND})


@dataclass
class ResourceWatch:
    resource: str
    hub: str
    alive: bool = False
    last_state: float | None = None
    hub_status: HubStatus | None = None  # None: no state received yet
    hub_detail: str = ""
    status_since: float = 0.0  # when the hub's status (or its detail) last changed
    commanded_seq: int = -1  # none yet: the first command sent (seq 0) is watched too
    commanded_at: float | None = None
    mirrored_seq: int = -1
    ever_seen: bool = False
    unmirrored: deque[tuple[int, float]] = field(default_factory=deque)  # (seq, first sent) not yet mirrored


@dataclass(frozen=True)
class Health:
    resource: str
    hub: str
    healthy: bool
    reason: str
    age: float | None  # seconds since the last state
    mirror_lag: int  # commands not yet mirrored
    note: str = ""  # a problem the hub reports that does not concern this controller's commands


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

    def state_received(self, resource: str, status: HubStatus, detail: str, mirrored_seq: int | None) -> None:
        w = self.watches.get(resource)
        if w is None:
            return
        w.last_state = self.clock()
        w.ever_seen = True
        if status != w.hub_status or detail != w.hub_detail:
            w.status_since = w.last_state
            w.hub_status, w.hub_detail = status, detail
        if mirrored_seq is not None:
            w.mirrored_seq = mirrored_seq
            while w.unmirrored and w.unmirrored[0][0] <= mirrored_seq:
                w.unmirrored.popleft()

    def command_sent(self, resource: str, seq: int) -> None:
        w = self.watches[resource]
        if seq != w.commanded_seq:
            w.commanded_seq = seq
            w.commanded_at = self.clock()
            if seq > w.mirrored_seq:
                w.unmirrored.append((seq, w.commanded_at))

    def reset_mirror(self, resource: str) -> None:
        """A new controller run: earlier mirrors say nothing about our commands."""
        w = self.watches[resource]
        w.mirrored_seq = -1
        w.unmirrored.clear()
        if w.commanded_at is not None and w.commanded_seq >= 0:
            w.unmirrored.append((w.commanded_seq, self.clock()))

    def health(self, resource: str) -> Health:
        w = self.watches[resource]
        now = self.clock()
        age = None if w.last_state is None else now - w.last_state
        lag = max(0, w.commanded_seq - w.mirrored_seq) if w.commanded_at is not None else 0
        reported = ""
        if w.hub_status is not None and w.hub_status not in HEALTHY_STATUSES:
            reported = f"hub reports {w.hub_status}" + (f": {w.hub_detail}" if w.hub_detail else "")
        # Not ours: every command we sent is mirrored (or we sent none), or the rejection was reported
        # before the oldest one that is not was sent, so the refused command came from elsewhere.
        ours = bool(w.unmirrored) and w.status_since >= w.unmirrored[0][1]
        foreign = w.hub_status == HubStatus.REJECTED and not ours
        reason = ""
        if not w.alive:
            reason = f"hub {w.hub} is not alive (no liveliness token)"
        elif age is None:
            reason = f"no state received from hub {w.hub} yet"
        elif age > self.stale_after:
            reason = f"state is stale: last one {age:.2f} s ago (bound {self.stale_after} s)"
        elif reported and not foreign:
            reason = reported
        elif lag and w.unmirrored and now - w.unmirrored[0][1] > self.mirror_bound:
            seq, sent = w.unmirrored[0]
            mirrored = f"seq {w.mirrored_seq}" if w.mirrored_seq >= 0 else "none of this controller's commands"
            reason = f"mirror lags: command seq {seq} sent {now - sent:.2f} s ago, hub mirrors {mirrored}"
        return Health(resource, w.hub, not reason, reason, age, lag, reported if foreign else "")

    def unhealthy(self) -> dict[str, str]:
        result = {}
        for resource in self.watches:
            h = self.health(resource)
            if not h.healthy:
                result[resource] = h.reason
        return result
