"""Throughput from order windows and ability spans: busy time counts overlaps once, cycles per variant."""

from __future__ import annotations

import pytest

from controller.production.throughput import (
    OrderWindow,
    ResourceTime,
    order_line,
    order_throughput,
    percentile,
    run_throughput,
    summary_lines,
)
from controller.timeline.model import Span


def test_busy_time_is_the_union_of_a_resources_spans_within_the_order() -> None:
    spans = [Span("ur", "move", 5, 15), Span("ur", "move", 10, 20), Span("ur", "move", 30, 50),  # ends after
             Span("nr", "tighten", 0, 12), Span("ur", "move", 60, 70), Span("cam", "look", 1, 2)]
    result = order_throughput(OrderWindow(1, "E-1", "full", 10, 40), spans, ["ur", "nr", "agv"])
    assert result.cycle_s == 30
    assert result.resources == {"ur": ResourceTime(20, 10), "nr": ResourceTime(2, 28), "agv": ResourceTime(0, 30)}


def test_percentiles_are_nearest_rank() -> None:
    assert percentile([3.0], 0.95) == 3.0
    assert percentile([float(v) for v in range(1, 101)], 0.5) == 50.0
    assert percentile([float(v) for v in range(1, 101)], 0.95) == 95.0
    assert percentile([10.0, 1.0, 5.0, 7.0], 0.5) == 5.0


def test_a_run_gives_engines_per_hour_and_cycle_times_per_variant() -> None:
    windows = [OrderWindow(1, "E-1", "full", 0, 40), OrderWindow(2, "E-2", "light", 40, 70),
               OrderWindow(3, "E-3", "full", 70, 130)]
    orders = [order_throughput(w, [], ["ur"]) for w in windows]
    run = run_throughput(orders, duration_s=180)
    assert run.per_hour == pytest.approx(60.0)
    assert (run.cycles["full"].count, run.cycles["full"].p50_s, run.cycles["full"].max_s) == (2, 40, 60)
    assert run.cycles["light"].p95_s == 30 and run.cycles["all"].count == 3
    lines = summary_lines(run)
    assert lines[0] == "throughput: 3 engines in 180.0 s = 60.0 engines per hour"
    assert "  cycle time full: 2 orders, p50 40.0 s, p95 60.0 s, max 60.0 s" in lines
    assert run_throughput([], 0).per_hour == 0.0


def test_the_line_per_order_names_its_cycle_and_busiest_resources() -> None:
    spans = [Span("ur", "move", 0, 30), Span("nr", "tighten", 0, 10), Span("agv", "go", 0, 1)]
    order = order_throughput(OrderWindow(4, "E-4", "light", 0, 40), spans, ["agv", "nr", "ur"])
    assert order_line(order, busiest=2) == "order 4 E-4 (light) done: cycle 40.0 s; ur busy 30.0 s (75%), " \
                                           "nr busy 10.0 s (25%)"
