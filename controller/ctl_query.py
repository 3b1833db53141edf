"""One question to the controller on a queryable of its own (`{station}/ctl/...`) and its typed answer.

What `hubctl orders`, an MES and the console ask goes the same way: the first reply is the answer; a
controller that failed, an answer that does not decode and no answer at all are refusals of the asker's
reply type, saying which.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import msgspec

from common.bus.protocol import Bus
from common.wire.messages import MessageError, decode, encode

Answer = TypeVar("Answer", bound=msgspec.Struct)


async def ask_controller(bus: Bus, key: str, request: msgspec.Struct, answer_type: type[Answer], *,
                         timeout: float, refuse: Callable[[str], Answer], unanswered: str) -> Answer:
    """The controller's `answer_type` on `key`, or `refuse(reason)`; `unanswered`: the reason when no
    controller answered within `timeout` (what the asker can say about where it asked)."""
    replies = await bus.get(key, payload=encode(request), timeout=timeout)
    for reply in replies:
        if not reply.ok:
            failure = reply.payload.decode(errors="replace")
            return refuse(f"the controller failed: {failure}")
        try:
            return decode(reply.payload, answer_type)
        except MessageError as exc:
            return refuse(f"unreadable reply from the controller: {exc}")
    return refuse(unanswered)
