"""Throughput, from order windows and ability spans: pure functions, no I/O.

Per order: its start and end, its cycle time, and each resource's busy time (the union of its
abilities' spans within the order's window: overlapping spans count once) and waiting time (the
rest of the window: the resource was idle while the product was on the station). Per run: engines
per hour (finished orders over the run's duration) and the cycle time's p50, p95 and max per
variant. The spans are the timeline's (`controller/timeline/model.py`, from a recording's states and
commands) or what the control loop reports; every time is on one clock, the caller's.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol


class AbilitySpan(Protocol):
    """An ability of a resource running from `start` to `end` (the timeline's `Span`: lane = resource)."""

    @property
    def lane(self) -> str: ...
    @property
    def start(self) -> float: ...
    @property
    def end(self) -> float: ...


@dataclass(frozen=True)
class OrderWindow:
    """When an order's product was on the station."""

    order_id: int
    product_id: str
    variant: str
    start: float
    end: float


@dataclass(frozen=True)
class ResourceTime:
    busy_s: float
    waiting_s: float


@dataclass(frozen=True)
class OrderThroughput:
    order_id: int
    product_id: str
    variant: str
    start: float
    end: float
    resources: Mapping[str, ResourceTime]

    @property
    def cycle_s(self) -> float:
        return self.end - self.start


@dataclass(frozen=True)
class CycleStats:
    count: int
    p50_s: float
    p95_s: float
    max_s: float


@dataclass(frozen=True)
class RunThroughput:
    orders: int
    duration_s: float
    per_hour: float  # finished orders (engines) per hour of the run
    cycles: Mapping[str, CycleStats]  # per variant, and "all"


ALL_VARIANTS = "all"


def _busy(intervals: Iterable[tuple[float, float]]) -> float:
    """The length of the union of the intervals."""
    total, reach = 0.0, -math.inf
    for start, end in sorted(intervals):
        if end <= reach:
            continue
        total += end - max(start, reach)
        reach = end
    return total


def order_throughput(window: OrderWindow, spans: Iterable[AbilitySpan], resources: Sequence[str]) -> \
        OrderThroughput:
    """The order's cycle and, for each of `resources`, its busy and waiting time within the window."""
    clipped: dict[str, list[tuple[float, float]]] = {r: [] for r in resources}
    for span in spans:
        start, end = max(span.start, window.start), min(span.end, window.end)
        if end > start and span.lane in clipped:
            clipped[span.lane].append((start, end))
    cycle = window.end - window.start
    times = {}
    for resource, intervals in clipped.items():
        busy = _busy(intervals)
        times[resource] = ResourceTime(busy, cycle - busy)
    return OrderThroughput(window.order_id, window.product_id, window.variant, window.start, window.end, times)


def percentile(values: Sequence[float], fraction: float) -> float:
    """The nearest-rank percentile (`fraction` 0.5: the median) of a non-empty sequence."""
    ordered = sorted(values)
    rank = max(1, math.ceil(fraction * len(ordered)))
    return ordered[rank - 1]


def cycle_stats(cycles: Sequence[float]) -> CycleStats:
    return CycleStats(len(cycles), percentile(cycles, 0.5), percentile(cycles, 0.95), max(cycles))


def run_throughput(orders: Sequence[OrderThroughput], duration_s: float) -> RunThroughput:
    """Engines per hour over a run of `duration_s`, and the cycle times per variant and of all orders."""
    by_variant: dict[str, list[float]] = {}
    for order in orders:
        by_variant.setdefault(order.variant, []).append(order.cycle_s)
    cycles = {variant: cycle_stats(values) for variant, values in by_variant.items()}
    if orders:
        cycles[ALL_VARIANTS] = cycle_stats([o.cycle_s for o in orders])
    per_hour = len(orders) * 3600.0 / duration_s if duration_s > 0 else 0.0
    return RunThroughput(len(orders), duration_s, per_hour, cycles)


# --- what `hubctl up` prints ----------------------------------------------------------------------

def order_line(order: OrderThroughput, busiest: int = 3) -> str:
    """One line per finished order: its cycle and the busiest resources' share of it."""
    shares = sorted(order.resources.items(), key=lambda item: (-item[1].busy_s, item[0]))[:busiest]
    cycle = order.cycle_s
    busy = ", ".join(f"{name} busy {t.busy_s:.1f} s ({t.busy_s / cycle:.0%})" if cycle > 0 else name
                     for name, t in shares)
    return (f"order {order.order_id} {order.product_id} ({order.variant}) done: cycle {cycle:.1f} s"
            + (f"; {busy}" if busy else ""))


def summary_lines(run: RunThroughput) -> list[str]:
    """The end of a run: engines per hour, then the cycle time per variant."""
    lines = [f"throughput: {run.orders} engines in {run.duration_s:.1f} s = {run.per_hour:.1f} engines per hour"]
    for variant, stats in run.cycles.items():
        lines.append(f"  cycle time {variant}: {stats.count} orders, p50 {stats.p50_s:.1f} s, "
                     f"p95 {stats.p95_s:.1f} s, max {stats.max_s:.1f} s")
    return lines
