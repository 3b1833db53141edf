"""The fake UR controller's flange watch: the simulated cell learns where the flange is before anyone sees it there.

The tool changer couples or releases a tool depending on whether the robot's flange is at
the tool's dock slot (the coupler's flange register, written by the cell,
``hubs.sim.cell.FlangeCoupling``). In the real cell that is physics: the changer is where
the robot is. Were the cell to poll the robot, a controller that saw the robot arrive
(RTDE, through the hub) could unlock the changer before the register said "at the slot",
and the simulated tool would fall (seen on a loaded machine). So the cell subscribes on
the command port (``{"cmd": "watch_flange", "slots": {"1": [6 rad], ...}, "tolerance":
rad}``), the fake sends ``{"slot": n}`` whenever the slot changes, and its RTDE streams
wait for the cell's ``{"ack": n}`` before sending the first sample that shows the change.
A cell that does not answer within ``ACK_TIMEOUT_S`` (starved, gone) only delays the
stream that long: less than the sim-mode driver's ``stale_after``.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Mapping, Sequence

log = logging.getLogger(__name__)

ACK_TIMEOUT_S = 0.5


def slot_of(q: Sequence[float], slots: Mapping[int, Sequence[float]], tolerance: float) -> int:
    """The dock slot whose robot pose `q` is at (every joint within `tolerance`), 0 when none."""
    for slot, target in slots.items():
        if max(abs(a - b) for a, b in zip(q, target, strict=True)) <= tolerance:
            return slot
    return 0


class FlangeWatch:
    """One watcher's subscription, on the command-port connection it was asked on."""

    def __init__(self, slots: Mapping[int, Sequence[float]], tolerance: float,
                 reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.slots = dict(slots)
        self.tolerance = tolerance
        self._reader, self._writer = reader, writer
        self._acked: int | None = None  # the slot the watcher has confirmed; None: nothing yet
        self._lock = asyncio.Lock()
        self.closed = asyncio.Event()

    async def announce(self, q: Sequence[float]) -> None:
        """Before a stream shows `q`: make sure the watcher knows the slot it is at."""
        slot = slot_of(q, self.slots, self.tolerance)
        if slot == self._acked or self.closed.is_set():
            return
        async with self._lock:  # several streams: one announcement, the others wait for it
            if slot == self._acked or self.closed.is_set():
                return
            try:
                self._writer.write(json.dumps({"slot": slot}).encode() + b"\n")
                await self._writer.drain()
                async with asyncio.timeout(ACK_TIMEOUT_S):
                    while True:  # an acknowledgement that came after its timeout is passed over
                        line = await self._reader.readline()
                        if not line:
                            raise ConnectionError("the flange watcher went away")
                        if int(json.loads(line)["ack"]) == slot:
                            break
                self._acked = slot
            except TimeoutError:
                log.warning("flange watcher did not acknowledge slot %d within %.1f s", slot, ACK_TIMEOUT_S)
                self._acked = slot  # do not hold every sample back; the watcher writes it when it can
            except (ConnectionError, OSError, ValueError, KeyError, TypeError):
                self.close()

    def close(self) -> None:
        self.closed.set()
        self._writer.close()
