"""The controller's intake of the hubs' states: decoded in batches, merged into the control loop at once.

For each state it also keeps the first mirror of each resource (the command state a restarted controller
takes, controller/command_hold.py), hands a held resource's mirror to the hold, notices a mirror of a command in
this controller's name with a seq it never sent (forged), and feeds the mirror-watchdog.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from common.bus.protocol import Bus, Sample
from common.model import Value
from common.wire.badpayload import BadPayloads
from common.wire.keys import Keys
from common.wire.messages import Codec, HubStatus, MessageError
from controller.command_hold import CommandHold
from controller.recording.schema import HubState

from .loop import ControlLoop
from .loopmeter import LoopMeter
from .watchdog import Watchdog

log = logging.getLogger("statehub.controller")

INGEST_BATCH_S = 0.002  # least time between two state batches: bursts join one batch


@dataclass(frozen=True)
class StateRoute:
    """What a resource's state key leads to: the resource, its codec, and (path, field) of each measured
    variable."""

    resource: str
    codec: Codec
    fields: tuple[tuple[str, str], ...]


class StateIngest:
    def __init__(self, loop: ControlLoop, keys: Keys, codecs: dict[str, Codec], controller_id: str,
                 watchdog: Watchdog, command_hold: CommandHold, meter: LoopMeter,
                 forged: Callable[[str, Any], None]) -> None:
        """`forged(resource, mirror)`: told of a mirror in our name with a seq this controller never sent."""
        self.loop = loop
        self.keys = keys
        self.controller_id = controller_id
        self.watchdog = watchdog
        self.command_hold = command_hold
        self.meter = meter
        self.forged = forged
        self.mirrors: dict[str, dict[str, Value]] = {}  # each resource's first mirror ({}: its hub has no command)
        self.routes = {
            keys.state(resource): StateRoute(resource, codec, tuple((v.path, v.name) for v in codec.measured))
            for resource, codec in codecs.items()}
        self._bad_states = BadPayloads(log, "dropped state")

    async def run(self, bus: Bus, wake: Callable[[], None]) -> None:
        # In batches: at hundreds of resources at 50 Hz, a loop wake-up, a core update and a tick
        # request per state cost more than decoding the state. Each resource's state key is declared
        # (`expect`): zenoh then routes it without matching it against every command key we publish.
        subscription = bus.subscribe(self.keys.all_state, batch_s=INGEST_BATCH_S, expect=self.routes.keys())
        async for batch in subscription.batches():
            self.meter.dropped = subscription.dropped
            if self.batch(batch):
                wake()

    def batch(self, samples: list[Sample]) -> bool:
        """Decode a batch (newest state per resource), feed the watchdog, and merge the measured values
        into the loop at once; True if any value changed. A state that cannot be decoded is dropped
        (logged at most once per key and interval, with a count); the rest of the batch is ingested."""
        watchdog, mirrors, controller_id, outbox = self.watchdog, self.mirrors, self.controller_id, self.loop.outbox
        held = self.command_hold.held
        measured: dict[str, Value] = {}
        published: list[float] = []
        hub_states: list[HubState] = []
        for sample in samples:
            route = self.routes.get(sample.key)
            if route is None:
                continue
            resource, codec = route.resource, route.codec
            try:
                state = codec.decode_state(sample.payload)
            except MessageError as exc:
                self._bad_states.report("an unknown sender", sample.key, str(exc))
                continue
            published.append(state.time)
            mirror = state.mirror
            mirrored_seq = mirror.seq if mirror is not None and mirror.controller == controller_id else None
            if mirrored_seq is not None and mirrored_seq > outbox.highest_seq(resource):
                self.forged(resource, mirror)
                mirrored_seq = None  # not a command this controller sent
            if resource not in mirrors:
                if mirror is not None:
                    mirrors[resource] = codec.values(mirror)
                elif state.status == HubStatus.NO_COMMAND:
                    mirrors[resource] = {}
            if resource in held:
                self.command_hold.arrived(resource, None if mirror is None else codec.values(mirror), state.status)
                held = self.command_hold.held
            watchdog.state_received(resource, state.status, state.detail, mirrored_seq)
            hub_states.append((resource, state.status, state.detail, mirrored_seq))
            for path, name in route.fields:
                value = getattr(state, name)
                if value is not None:  # unknown (device lost): the last known value stands
                    measured[path] = value
        changed = self.loop.ingest(measured, hub_states)
        now = time.time()  # ingested now, when the core holds them: the age includes decoding the batch
        self.meter.ages.extend(now - t for t in published)
        return bool(changed)
