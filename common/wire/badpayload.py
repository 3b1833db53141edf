"""Rate-limited reports of payloads a process drops (garbage, oversized, another sender's).

A flood of bad payloads must not become a flood of log lines: each (sender, key) is
logged at once the first time, then at most once per `interval_s`, with how many were
dropped since its last line. What is held back is logged when the interval ends, so a
flood that stops is still counted in full.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass

DEFAULT_INTERVAL_S = 10.0
MAX_TRACKED = 1000  # distinct (sender, key) counted apart; beyond, a forged sender per message shares one count
OTHERS = "(other senders)"


@dataclass
class _Count:
    logged_at: float
    held: int = 0  # dropped since the last line
    reason: str = ""
    flush_due: bool = False


class BadPayloads:
    """`report(sender, key, reason)` for each dropped payload; `what` says what was dropped
    ("dropped malformed command"), the logger's own prefix says who dropped it."""

    def __init__(self, logger: logging.Logger, what: str, *, prefix: str = "",
                 interval_s: float = DEFAULT_INTERVAL_S, level: int = logging.WARNING) -> None:
        self.log, self.what, self.prefix = logger, what, prefix
        self.interval_s, self.level = interval_s, level
        self._counts: dict[tuple[str, str], _Count] = {}
        self.total = 0

    def report(self, sender: str, key: str, reason: str) -> None:
        self.total += 1
        if (sender, key) not in self._counts and len(self._counts) >= MAX_TRACKED:
            sender = OTHERS
        now = time.monotonic()
        count = self._counts.get((sender, key))
        if count is None or (now - count.logged_at >= self.interval_s and not count.flush_due):
            held = count.held if count is not None else 0
            self._counts[(sender, key)] = _Count(now)
            self._line(sender, key, reason, held + 1)
            return
        count.held += 1
        count.reason = reason
        if not count.flush_due:
            count.flush_due = True
            self._flush_later(sender, key, count.logged_at + self.interval_s - now)

    def _flush_later(self, sender: str, key: str, delay: float) -> None:
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop (a synchronous caller): the next report after the interval logs it
            self._counts[(sender, key)].flush_due = False
            return
        loop.call_later(max(0.0, delay), self._flush, sender, key)

    def _flush(self, sender: str, key: str) -> None:
        count = self._counts.get((sender, key))
        if count is None or not count.flush_due:
            return
        self._counts[(sender, key)] = _Count(time.monotonic())
        self._line(sender, key, count.reason, count.held)

    def _line(self, sender: str, key: str, reason: str, count: int) -> None:
        times = "" if count == 1 else f" ({count} since the last report)"
        with contextlib.suppress(Exception):  # logging must never end the loop that drops garbage
            self.log.log(self.level, "%s%s on %s from %s%s: %s", self.prefix, self.what, key, sender, times,
                         reason)
