"""The outbox's commands on the bus: each encoded in this controller's name and epoch, published on its
resource's command key, and told to the mirror-watchdog; every command again at the command rate."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterable, Mapping

from common.bus.protocol import Bus
from common.wire.keys import Keys
from common.wire.messages import Codec

from .loop import ControlLoop
from .outbox import Command
from .watchdog import Watchdog


class CommandPublisher:
    def __init__(self, bus: Bus, keys: Keys, codecs: Mapping[str, Codec], controller_id: str,
                 epoch: Callable[[], int], watchdog: Watchdog) -> None:
        """`epoch()`: the station hold's epoch now (a forged command makes the controller take a new one)."""
        self.bus = bus
        self.keys = keys
        self.codecs = codecs
        self.controller_id = controller_id
        self.epoch = epoch
        self.watchdog = watchdog

    def publish(self, commands: Iterable[Command]) -> None:
        for command in commands:
            codec = self.codecs[command.resource]
            message = codec.command(command.values, seq=command.seq, controller=self.controller_id, epoch=self.epoch())
            self.bus.publish(self.keys.cmd(command.resource), codec.encode_command(message))
            self.watchdog.command_sent(command.resource, command.seq)

    async def resend(self, loop: ControlLoop, held: Callable[[], frozenset[str]], rate_hz: float,
                     stop: asyncio.Event) -> None:
        """Every command at `rate_hz` until `stop`: a hub that restarted or missed one catches up."""
        period = 1.0 / rate_hz
        while not stop.is_set():
            self.publish(loop.resend(held()))
            await asyncio.sleep(period)
