"""The overview's only handle on the station bus: it reads, and nothing else.

`StationReader` wraps the process's bus and offers what the overview reads: the controller's status
stream, its whole picture and a plan's details (the two queryables that only answer). It has no
`publish`, no `declare_*` and no query to any other key, so nothing the overview builds on it can
put a command, answer a query or ask `ctl/request` or `ctl/orders`; in `tls` mode the station's
access control says the same of its certificate (the `viewer` role, common/config/acl.py).
"""

from __future__ import annotations

from common.bus.protocol import Bus, Sample, Subscription
from common.wire.ctl import PlanDetails, StatusMessage
from common.wire.keys import Keys
from controller.console.statusview import ask, fetch_plan


class StationReader:
    __slots__ = ("__bus", "keys")

    def __init__(self, bus: Bus, keys: Keys) -> None:
        self.__bus = bus  # private: the overview's code reaches the bus only through the methods below
        self.keys = keys

    def statuses(self) -> Subscription[Sample]:
        """Every sample of `{station}/ctl/status` in order (a delta applies only to the picture before it)."""
        return self.__bus.subscribe(self.keys.ctl("status"), coalesce=False)

    async def full_status(self) -> StatusMessage | None:
        """The controller's whole picture (a query on its status key), or None."""
        status = await ask(self.__bus, self.keys.ctl("status"), StatusMessage)
        return status if isinstance(status, StatusMessage) else None

    async def plan(self, plan_id: int) -> PlanDetails | None:
        """The steps of plan `plan_id` and what its pending steps wait for, or None."""
        return await fetch_plan(self.__bus, self.keys, plan_id)
