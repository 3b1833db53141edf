"""What the fault tests check on a fault station's recorded streams: tightenings, operation states, commands.

"Tightened exactly once" is checked on what the devices did (rising edges of `nr.tqr_m`
at the pose the robot reported), on what the controller believed (state snapshots,
operation states) and on what it persisted (`assert_station_done_each_bolt_once`).
"""

from __future__ import annotations

from itertools import pairwise
from typing import Any

from common.model import OperationState
from common.wire.ctl import StatusMessage
from tests.fault_station.harness import Station
from tests.fault_station.model import BOLT_POSES, BOLTS, bolt
from tests.fault_station.watcher import Seen, rising_edges, value_published_before

RUN_TIMEOUT_S = 40.0  # the station needs ~5 s; generous for a loaded 2-core machine
POSE_OF = {pose: i for i, pose in BOLT_POSES.items()}
OPERATIONS = tuple(f"TightenBolt{i}" for i in BOLTS)


def tightenings(station: Station) -> list[tuple[int | None, Seen]]:
    """Each tightening the nutrunner did (a rising edge of tqr_m), with the bolt the robot was at when the
    nutrunner's hub reported it (by the hubs' own time stamps, not by when the watcher got each state)."""
    ur_states = station.watch.states("ur")
    return [(POSE_OF.get(value_published_before(ur_states, "pos_m", edge.message.time)), edge)
            for edge in rising_edges(station.watch.states("nr"), "tqr_m")]


def robot_around_tightenings(station: Station, window_s: float = 1.5) -> str:
    """For a failure message: each tightening and the robot's states published around it (hub time,
    receive time, seq, pose), so that a missing or late stream shows."""
    ur_states = station.watch.states("ur")
    lines = []
    for i, edge in tightenings(station):
        t = edge.message.time
        lines.append(f"tightening at hub time {t:.3f} (received {edge.at:.3f}, nr seq {edge.message.seq}): bolt {i}")
        near = [s for s in ur_states if abs(s.message.time - t) <= window_s]
        changes = [s for k, s in enumerate(near) if k == 0 or s.message.pos_m != near[k - 1].message.pos_m]
        lines += [f"    ur {s.message.time:.3f} (received {s.at:.3f}, seq {s.message.seq}): {s.message.pos_m}"
                  for s in changes]
        lines.append(f"    ({len(near)} ur states within {window_s} s)")
    return "\n".join(lines)


def tightened_at(station: Station) -> dict[int | None, int]:
    counts: dict[int | None, int] = {}
    for i, _ in tightenings(station):
        counts[i] = counts.get(i, 0) + 1
    return counts


def op_states(status: StatusMessage) -> dict[str, str]:
    return {op.name: op.state for op in status.operations}


def assert_station_done_each_bolt_once(station: Station) -> None:
    """The station finished, every bolt was tightened exactly once, and everyone agrees."""
    watch = station.watch
    assert watch.finished(), station.describe()
    # What the devices did: one tightening per bolt pose, none anywhere else, no failure.
    first_seqs = {r: (s[0].message.seq if (s := watch.states(r)) else None) for r in ("nr", "ur")}
    assert tightened_at(station) == dict.fromkeys(BOLTS, 1), \
        f"tightenings per bolt: {tightened_at(station)} (None: the robot was at no bolt); first seqs {first_seqs}\n" \
        + robot_around_tightenings(station)
    assert not any(s.message.fail_m for s in watch.states("nr"))
    # What the controller believed: each bolt goes placed -> tightened once, and stays (snapshots come
    # at 1 Hz: wait for one that is newer than the end).
    station.wait_for(lambda: all(watch.snapshot().get(bolt(i)) == "tightened" for i in BOLTS), 3,
                     "a state snapshot with every bolt tightened")
    snapshots = watch.snapshots()
    for i in BOLTS:
        values = [s.message.values[bolt(i)] for s in snapshots]
        changes = [b for a, b in pairwise(values) if a != b]
        assert changes in ([], ["tightened"]), f"{bolt(i)} went {values}"
        assert values[-1] == "tightened"
    # Each operation finishes once and stays finished, across controller restarts.
    for name in OPERATIONS:
        seen = [op_states(s.message)[name] for s in watch.statuses()]
        first = seen.index(OperationState.FINISHED)
        assert all(state == OperationState.FINISHED for state in seen[first:]), f"{name} left finished: {seen[first:]}"
    # What is persisted.
    persisted = station.persisted()
    for i in BOLTS:
        assert persisted[bolt(i)] == "tightened"
    for name in OPERATIONS:
        assert persisted[f"op.{name}"] == OperationState.FINISHED
    assert not station.dead(), f"processes exited: {station.dead()}"
    loop = watch.current_status().loop  # the controller measures its own loop (tests/bench/bench_station.py reads it)
    assert loop is not None and loop.ticks > 0 and loop.states > 0 and loop.tick_ms_median > 0


def nr_running_on_bolt(station: Station, nth: int) -> Any:
    """Wait until the nutrunner runs (run_m, no torque yet) for the nth time; returns that state."""
    def running() -> Any:
        states = station.watch.states("nr")
        if len(rising_edges(states, "run_m")) < nth:
            return None
        last = states[-1].message
        return last if last.run_m and not last.tqr_m else None

    return station.wait_for(running, RUN_TIMEOUT_S, f"the nutrunner runs for the {nth}. time", poll=0.002)


def controller_commands(station: Station, resource: str, controller: str | None = None) -> list[Seen]:
    """Commands the controller (any run, or one by id) published; the tests' own garbage never decodes."""
    return [c for c in station.watch.commands(resource)
            if c.message.controller.startswith(f"{station.config.controller.name}-")
            and (controller is None or c.message.controller == controller)]


def between(seen: list[Seen], start: float, end: float) -> list[Seen]:
    return [s for s in seen if start <= s.at <= end]
