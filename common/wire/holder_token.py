"""Who holds the station: the one controller whose commands the hubs apply (issue 12, DESIGN.md §11).

A controller holds the station with a liveliness token on
`{station}/ctl/holder/{epoch}/{controller}/{host}/{pid}` and puts its `epoch` in every
command. The epoch only grows (the controller persists it) and is taken afresh on each
start, so every run of a controller is a new identity `(controller, epoch)`. Hubs apply
the commands of the live holder that ranks highest (`Holder.rank`: epoch, then id), and
order `seq` per identity: a command with any other identity, however high its `seq`, is
refused and cannot hold back the holder's next command.

Tools that command hubs in place of the controller (tests, `hubctl modeltest`) declare a
holder too (`declare_holder`), with epoch 0.
"""

from __future__ import annotations

import os
import re
import socket
from collections.abc import Iterable
from dataclasses import dataclass

from common.bus.protocol import Bus, Token
from common.wire.keys import Keys


@dataclass(frozen=True)
class Holder:
    epoch: int
    controller: str
    host: str = "?"
    pid: int = 0

    @property
    def rank(self) -> tuple[int, str]:
        """Of two live holders the hubs follow the higher: the later epoch, then the larger id."""
        return self.epoch, self.controller

    def is_sender(self, controller: str, epoch: int) -> bool:
        return controller == self.controller and epoch == self.epoch

    def key(self, keys: Keys) -> str:
        return keys.holder(self.epoch, self.controller, self.host, self.pid)

    def describe(self) -> str:
        return f"controller {self.controller} (epoch {self.epoch}, host {self.host}, pid {self.pid})"

    @staticmethod
    def parse(keys: Keys, key: str) -> Holder | None:
        """The holder a token key names, or None for a key of another shape."""
        parts = key.split("/")
        if len(parts) != 7 or parts[:3] != [keys.station, "ctl", "holder"]:
            return None
        epoch, controller, host, pid = parts[3:]
        if not epoch.isdigit() or not pid.isdigit():
            return None
        return Holder(int(epoch), controller, host, int(pid))


def this_host() -> str:
    """This machine's name as one key chunk (characters a key cannot hold become '_')."""
    return re.sub(r"[/*$?#@\s]", "_", socket.gethostname()) or "unknown"


def this_process(controller: str, epoch: int) -> Holder:
    return Holder(epoch, controller, this_host(), os.getpid())


def declare_holder(bus: Bus, keys: Keys, controller: str, epoch: int = 0) -> Token:
    """Hold the station as `controller` in `epoch` (a tool's or a test's hold: nothing persisted)."""
    return bus.declare_liveliness(this_process(controller, epoch).key(keys))


def highest(holders: Iterable[Holder]) -> Holder | None:
    """The holder the hubs follow among `holders`."""
    return max(holders, key=lambda h: h.rank, default=None)
