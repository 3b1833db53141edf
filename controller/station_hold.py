"""The controller's hold on the station (common/wire/holder_token.py): one controller commands the hubs.

On start the controller asks who holds the station; if another controller does, it refuses
to start (`ControllerConflict`, exit status `EXIT_CONFLICT`), naming it. Otherwise it takes
the next epoch (persisted in its SQLite file before it is used, so it only grows) and
declares its holder token before it sends any command. While it runs:

* another holder that outranks it (two controllers started at the same moment): it stops,
  naming the other, so that the hubs, which follow the higher one, never see two;
* a hub mirrors a command of this controller and epoch with a `seq` it never sent: a
  forged command that would hold back every genuine one. It takes a new epoch (`renew`):
  the hubs order `seq` per epoch, so its next command is applied at once.
"""

from __future__ import annotations

import asyncio
import logging

from common.bus.protocol import Bus, Token
from common.wire.holder_token import Holder, this_process
from common.wire.keys import Keys
from controller.state import StateStore

log = logging.getLogger("statehub.controller")

EXIT_CONFLICT = 3  # `python -m controller`'s exit status when another controller holds the station
HOLDER_QUERY_S = 1.0  # how long a starting controller waits for holders to answer


class ControllerConflict(RuntimeError):
    """Another controller holds the station."""


class StationHold:
    def __init__(self, bus: Bus, keys: Keys, store: StateStore, controller_id: str) -> None:
        self.bus, self.keys, self.store, self.controller_id = bus, keys, store, controller_id
        self.holder: Holder | None = None
        self.lost: ControllerConflict | None = None  # set when another holder outranked this one
        self._token: Token | None = None

    @property
    def epoch(self) -> int:
        if self.holder is None:
            raise RuntimeError("the station is not held yet (StationHold.acquire)")
        return self.holder.epoch

    async def acquire(self) -> None:
        """Hold the station in the next epoch; raise ControllerConflict if another controller holds it."""
        tokens = await self.bus.alive_tokens(self.keys.all_holders, timeout=HOLDER_QUERY_S)
        others = sorted({h for k in tokens if (h := Holder.parse(self.keys, k)) is not None},
                        key=lambda h: h.rank, reverse=True)
        if others:
            raise ControllerConflict(
                f"station {self.keys.station} is held by {others[0].describe()}: stop it first "
                f"(only one controller may command the hubs); {self.controller_id} did not start")
        self._declare(self._next_epoch())

    def renew(self, reason: str) -> None:
        """Hold the station in a new epoch (the hubs then order this controller's `seq` afresh)."""
        old = self._token
        self._declare(self._next_epoch())
        log.error("%s: holding the station in epoch %d now", reason, self.epoch)
        if old is not None:
            old.undeclare()  # after the new token: the hubs are never left without a holder

    def release(self) -> None:
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    async def watch(self, stop: asyncio.Event) -> None:
        """Stop the controller (`stop`, and `lost` says why) when a holder that outranks it appears."""
        async for event in self.bus.watch_liveliness(self.keys.all_holders):
            other = Holder.parse(self.keys, event.key)
            if not event.alive or other is None or other.controller == self.controller_id:
                continue
            if self.holder is not None and other.rank > self.holder.rank:
                self.lost = ControllerConflict(
                    f"station {self.keys.station} is now held by {other.describe()}, which outranks this "
                    f"controller {self.holder.describe()}: stopping")
                log.error("%s", self.lost)
                stop.set()
                return
            log.error("another controller holds the station too: %s; the hubs follow this one, which outranks it",
                      other.describe())

    def _next_epoch(self) -> int:
        stored = self.store.meta("epoch", 0)
        epoch = (stored if isinstance(stored, int) else 0) + 1
        self.store.save({}, {"epoch": epoch})  # persisted before any command carries it
        return epoch

    def _declare(self, epoch: int) -> None:
        self.holder = this_process(self.controller_id, epoch)
        self._token = self.bus.declare_liveliness(self.holder.key(self.keys))
