"""A reader's side of `{station}/ctl/status`: the controller's deltas merged back into full statuses.

The controller publishes what changed since its previous status (`StatusMessage.seq` counts them) and
every few seconds the whole picture (`full`); controller/statusfeed.py says why. `StatusView.apply`
turns that stream back into full `StatusMessage`s, which is what consoles, `hubctl up` and the tests
read. A delta that does not follow the picture held (a status missed, another controller) cannot be
applied: `StatusFollower` then asks the controller for its picture (a query on the status key), and
asks the same when it starts, so that a reader that connects late has everything at once.

    follower = StatusFollower(bus, keys)
    async for sample in bus.subscribe(keys.ctl("status"), coalesce=False):
        status = await follower.take(sample.payload)   # a full status, or None (nothing new yet)

The plan's steps and guards are not in a status: `fetch_plan(bus, keys, status.plan.id)`.
"""

from __future__ import annotations

import logging

import msgspec

from common.bus.protocol import Bus, BusError
from common.wire.ctl import EVENT_WINDOW, PlanDetails, StatusMessage
from common.wire.keys import Keys
from common.wire.messages import Message, MessageError, decode

log = logging.getLogger("statehub.status")

QUERY_TIMEOUT_S = 1.0


class StatusView:
    """The newest full status, from full statuses and the deltas that follow them."""

    def __init__(self) -> None:
        self.status: StatusMessage | None = None
        self.needs_full = True  # no picture yet, or a delta was missed: only a full status helps

    def apply(self, message: StatusMessage) -> StatusMessage | None:
        """The full status after `message`, or None when it adds nothing (older than the picture held) or
        cannot be applied (then `needs_full`)."""
        held = self.status
        same = held is not None and held.controller == message.controller
        if same and held is not None and (message.seq < held.seq or (message.seq == held.seq and not message.full)):
            return None  # a full picture asked for overtook it
        if message.full:
            self.status, self.needs_full = message, False
            return message
        if held is None or not same or self.needs_full or message.seq != held.seq + 1:
            self.needs_full = True
            return None
        self.status = merged = merge(held, message)
        return merged


def merge(held: StatusMessage, delta: StatusMessage) -> StatusMessage:
    """The full status `held` updated by the delta that follows it."""
    operations = {op.name: op for op in held.operations}
    operations.update((op.name, op) for op in delta.operations)
    health = {h.resource: h for h in held.health}
    health.update((h.resource, h) for h in delta.health)
    plan = delta.plan if delta.plan is not None else held.plan
    if delta.plan_done is not None and plan is not None:
        plan = msgspec.structs.replace(plan, done=delta.plan_done)
    return msgspec.structs.replace(
        delta, full=True, operations=list(operations.values()), health=list(health.values()), plan=plan,
        plan_done=None, events=(held.events + delta.events)[-EVENT_WINDOW:])


async def ask(bus: Bus, key: str, type_: type[Message], timeout: float = QUERY_TIMEOUT_S) -> Message | None:
    """The first readable answer of a query on `key`, or None (nobody answered, or not in time)."""
    try:
        replies = await bus.get(key, timeout=timeout)
    except BusError as exc:  # the session closing under us
        log.debug("query %s: %s", key, exc)
        return None
    for reply in replies:
        if reply.ok:
            try:
                return decode(reply.payload, type_)
            except MessageError as exc:
                log.warning("unreadable answer on %s: %s", key, exc)
    return None


async def fetch_plan(bus: Bus, keys: Keys, plan_id: int, timeout: float = QUERY_TIMEOUT_S) -> PlanDetails | None:
    """The steps and guards of the controller's plan `plan_id` (None: no such plan, or no answer)."""
    if not plan_id:
        return None
    details = await ask(bus, keys.plan(plan_id), PlanDetails, timeout)
    return details if isinstance(details, PlanDetails) else None


class StatusFollower:
    """A `StatusView` that asks the controller for its picture when it has none or missed a delta."""

    def __init__(self, bus: Bus, keys: Keys) -> None:
        self.bus = bus
        self.keys = keys
        self.view = StatusView()

    @property
    def status(self) -> StatusMessage | None:
        return self.view.status

    async def take(self, payload: bytes) -> StatusMessage | None:
        """The full status after this sample of the status key (raises MessageError if unreadable)."""
        merged = self.view.apply(decode(payload, StatusMessage))
        if merged is None and self.view.needs_full:
            full = await ask(self.bus, self.keys.ctl("status"), StatusMessage)
            if isinstance(full, StatusMessage):
                merged = self.view.apply(full)
        return merged
