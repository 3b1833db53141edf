"""The controller loop's own figures between two statuses (`StatusMessage.loop`): tick durations, and the
age of each state when it was ingested."""

from __future__ import annotations

import time

from common.wire.ctl import LoopStats


class LoopMeter:
    def __init__(self) -> None:
        self.dropped = 0  # cumulative, set by the ingest loop from its subscription
        self._dropped_before = 0
        self._restart(time.monotonic())

    def _restart(self, now: float) -> None:
        self.since = now
        self.ticks: list[float] = []  # seconds
        self.ages: list[float] = []  # seconds from a state's publication to its ingestion

    def take(self) -> LoopStats:
        now = time.monotonic()
        ticks, ages = sorted(self.ticks), sorted(self.ages)
        stats = LoopStats(
            window_s=now - self.since, ticks=len(ticks), tick_ms_median=_ms(ticks, 0.5), tick_ms_p99=_ms(ticks, 0.99),
            tick_ms_max=_ms(ticks, 1.0), states=len(ages), states_dropped=self.dropped - self._dropped_before,
            state_age_ms_median=_ms(ages, 0.5), state_age_ms_p99=_ms(ages, 0.99), state_age_ms_max=_ms(ages, 1.0))
        self._dropped_before = self.dropped
        self._restart(now)
        return stats


def _ms(ordered: list[float], q: float) -> float:
    return 1000.0 * ordered[min(len(ordered) - 1, int(len(ordered) * q))] if ordered else 0.0
