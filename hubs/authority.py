"""Whose commands a hub applies: only the station's holder's (common/wire/holder_token.py), in its epoch.

`Authority` follows the holder tokens (`{station}/ctl/holder/**`) and says, for each command
payload, whether it comes from the live holder that ranks highest; `seq` is ordered per
(controller, epoch) by the runtime. A command from anyone else (no holder yet, an old
epoch, another controller, a forged id) is dropped before it is decoded, changes no
output, no mirror and no status, and is counted in a rate-limited log line. When a
controller restarts it holds the station under a new id and a higher epoch: its token
arrives before its first command, so that command is applied at once, and the old
epoch's commands are refused from then on.
"""

from __future__ import annotations

import logging

from common.bus.protocol import Bus, Sample
from common.wire.badpayload import BadPayloads
from common.wire.holder_token import Holder, highest
from common.wire.keys import Keys
from common.wire.messages import Codec, CommandMessage, CommandSender, DomainError, MessageError, ModelMismatch

log = logging.getLogger("statehub.hub")


class Authority:
    def __init__(self, hub: str, keys: Keys) -> None:
        self.hub, self.keys = hub, keys
        self.live: dict[str, Holder] = {}  # token key -> holder
        self.holder: Holder | None = None
        prefix = f"hub {hub}: "
        self.malformed = BadPayloads(log, "dropped malformed command", prefix=prefix)
        self.foreign = BadPayloads(log, "ignored command", prefix=prefix)
        self.rejected = BadPayloads(log, "rejected command", prefix=prefix)

    def token(self, key: str, alive: bool) -> None:
        """A holder token appeared (`alive`) or went."""
        holder = Holder.parse(self.keys, key)
        if holder is None:
            log.warning("hub %s: ignored a holder token of unknown shape: %s", self.hub, key[:200])
            return
        if alive:
            self.live[key] = holder
        else:
            self.live.pop(key, None)
        current = highest(self.live.values())
        if current != self.holder:
            log.info("hub %s: the station is held by %s", self.hub,
                     current.describe() if current is not None else "no controller")
            self.holder = current

    async def follow(self, bus: Bus) -> None:
        async for event in bus.watch_liveliness(self.keys.all_holders):
            self.token(event.key, event.alive)

    def refusal(self, controller: str, epoch: int) -> str | None:
        """Why a command from `controller` in `epoch` is refused, or None when it is the holder's."""
        holder = self.holder
        if holder is not None and holder.is_sender(controller, epoch):
            return None
        held = holder.describe() if holder is not None else "no controller"
        return f"not the station's holder (held by {held})"

    def decode(self, codec: Codec, sample: Sample) -> CommandMessage | None:
        """The holder's command in `sample`, or None when it is dropped (logged, rate-limited): too
        long, unreadable, or not the holder's. A command of the holder that is out of its domain or
        of another model raises (DomainError, ModelMismatch): the hub says so in its status."""
        try:
            sender = codec.sender(sample.payload)
        except MessageError as exc:
            self.malformed.report("an unknown sender", sample.key, str(exc))
            return None
        who = _who(sender)
        refusal = self.refusal(sender.controller, sender.epoch)
        if refusal is not None:
            self.foreign.report(who, sample.key, refusal)
            return None
        try:
            return codec.decode_command(sample.payload)
        except (DomainError, ModelMismatch) as exc:
            self.rejected.report(who, sample.key, str(exc))
            raise
        except MessageError as exc:
            self.malformed.report(who, sample.key, str(exc))
            return None


def _who(sender: CommandSender) -> str:
    return f"{sender.controller} (epoch {sender.epoch})"
