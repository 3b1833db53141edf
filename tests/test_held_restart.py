"""A controller restart while one hub cannot be heard: real processes, real Zenoh on loopback (as test_faults.py).

The robot's hub is frozen (SIGSTOP) between two bolts (the robot sent to the next one), then the controller is
killed and restarted with a short mirror wait. The restarted controller commands the nutrunner (its mirror came) but
sends nothing at all to the robot while its hub is frozen; once thawed, the hub's mirror arrives and the
controller's commands to the robot resume from it (its target pose, not the model's initial `home`); the
station then finishes with each bolt tightened once.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.model import OperationState
from common.wire.ctl import MirrorsMissing
from tests.fault_station.checks import RUN_TIMEOUT_S, assert_station_done_each_bolt_once, controller_commands, op_states
from tests.fault_station.harness import Station
from tests.fault_station.model import BOLTS
from tests.fault_station.watcher import rising_edges

pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def station(tmp_path: Path) -> Iterator[Station]:
    with Station(tmp_path) as s:
        yield s


@pytest.mark.slow
def test_a_resource_without_mirror_at_restart_is_sent_nothing_until_its_mirror_arrives(station: Station) -> None:
    station.start()
    first = station.wait_for(station.watch.status, 5, "a status").controller

    def between_bolts() -> bool:  # a bolt done and recorded, the nutrunner idle: no result can be lost
        states = station.watch.states("nr")
        last = states[-1].message if states else None
        status = station.watch.status()
        return last is not None and not last.run_m and not last.tqr_m \
            and 1 <= len(rising_edges(states, "tqr_m")) < len(BOLTS) \
            and status is not None and OperationState.FINISHED in op_states(status).values()

    station.wait_for(between_bolts, RUN_TIMEOUT_S, "a bolt done and the nutrunner idle", poll=0.002)
    frozen_at = station.freeze("ur10")
    station.kill("controller")
    station.start_controller(fresh=False, mirror_wait=0.5)
    status = station.wait_for(
        lambda: s if (s := station.watch.status()) is not None and s.controller != first else None,
        15, "a status from the restarted controller")
    second = status.controller
    station.wait_for(lambda: controller_commands(station, "nr", second), 10, "the nutrunner commanded")
    station.wait_for(lambda: any(isinstance(e, MirrorsMissing) for e in station.watch.current_status().events), 5,
                     "the held robot reported")
    time.sleep(1.5)  # 15 re-send periods
    assert controller_commands(station, "ur", second) == [], "a command went to the robot without its mirror"
    (event,) = [e for e in station.watch.current_status().events if isinstance(e, MirrorsMissing)]
    assert event.resources == {"ur10": ["ur"]}

    thawed_at = station.thaw("ur10")
    sent = station.wait_for(lambda: controller_commands(station, "ur", second), 15, "the robot commanded again")
    applied = what_the_hub_had_applied(station, first, frozen_at, thawed_at)
    assert "home" not in applied, applied
    assert sent[0].message.ref_pos_c in applied, f"first command after the mirror: {sent[0].message}, " \
                                                 f"the hub had applied one of {applied}"
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes")
    assert_station_done_each_bolt_once(station)


def what_the_hub_had_applied(station: Station, first: str, frozen_at: float, thawed_at: float) -> set[str]:
    """The robot's ref_pos_c values the frozen hub may have applied from the first controller: those it was seen
    mirroring after the thaw, and the first controller's commands from the newest the hub was seen mirroring
    before the freeze to the newest sent before it. Both, because a command sent just before the freeze waits
    in the hub's socket and is applied after the thaw (its mirror then says so), and because the thawed hub's
    first states can reach the controller before its link to the watcher is back."""
    states = station.watch.states("ur")
    thawed = {s.message.mirror.ref_pos_c for s in states
              if s.at >= thawed_at and s.message.mirror is not None and s.message.mirror.controller == first}
    mirrored = [s.message.mirror.seq for s in states if s.at < frozen_at and s.message.mirror is not None
                and s.message.mirror.controller == first]
    return thawed | {c.message.ref_pos_c for c in controller_commands(station, "ur", first)
                     if c.at < frozen_at and c.message.seq >= max(mirrored, default=0)}
