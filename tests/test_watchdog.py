"""The mirror-watchdog's verdicts, with a hand-driven clock."""

from __future__ import annotations

import pytest

from common.wire.messages import HubStatus
from controller.watchdog import HEALTHY_STATUSES, Watchdog


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def make() -> tuple[Watchdog, Clock]:
    clock = Clock()
    return Watchdog({"nr": "pi-tool", "lift": "pi-tool", "ur": "ur10"}, stale_after=0.5, mirror_bound=1.0,
                    clock=clock), clock


def test_a_resource_is_healthy_only_when_alive_fresh_and_mirroring() -> None:
    dog, clock = make()
    assert "not alive" in dog.health("nr").reason
    dog.hub_alive("pi-tool", True)
    assert "no state received" in dog.health("nr").reason
    dog.state_received("nr", HubStatus.OK, "", None)
    assert dog.health("nr").healthy
    clock.now += 0.6
    assert "stale" in dog.health("nr").reason
    dog.state_received("nr", HubStatus.OK, "", None)
    assert dog.health("nr").healthy


def test_liveliness_loss_marks_every_resource_of_the_hub() -> None:
    dog, _ = make()
    dog.hub_alive("pi-tool", True)
    for r in ("nr", "lift"):
        dog.state_received(r, HubStatus.OK, "", None)
    dog.hub_alive("pi-tool", False)
    assert set(dog.unhealthy()) == {"nr", "lift", "ur"}
    assert "pi-tool is not alive" in dog.unhealthy()["lift"]


def test_mirror_lag_beyond_the_bound_is_reported() -> None:
    dog, clock = make()
    dog.hub_alive("pi-tool", True)
    dog.command_sent("nr", 5)
    dog.state_received("nr", HubStatus.OK, "", 4)
    clock.now += 0.4
    dog.state_received("nr", HubStatus.OK, "", 4)
    assert dog.health("nr").healthy  # within the bound
    clock.now += 0.7
    dog.state_received("nr", HubStatus.OK, "", 4)
    health = dog.health("nr")
    assert not health.healthy and "mirror lags" in health.reason and health.mirror_lag == 1
    dog.state_received("nr", HubStatus.OK, "", 5)
    assert dog.health("nr").healthy


def test_hub_reported_problems_are_unhealthy() -> None:
    dog, _ = make()
    dog.hub_alive("ur10", True)
    dog.state_received("ur", HubStatus.DEVICE_LOST, "RTDE silent for 0.3 s", None)
    assert dog.health("ur").reason == "hub reports device_lost: RTDE silent for 0.3 s"


@pytest.mark.parametrize("status", list(HubStatus))
def test_every_status_but_ok_and_no_command_is_a_problem_the_hub_reports(status: HubStatus) -> None:
    dog, _ = make()
    dog.hub_alive("ur10", True)
    dog.state_received("ur", status, "why", None)
    health = dog.health("ur")
    if status in HEALTHY_STATUSES:
        assert health.healthy and health.reason == ""
    else:
        # A rejection with none of our commands outstanding was another controller's: only noted.
        said = health.note if status is HubStatus.REJECTED else health.reason
        assert said == f"hub reports {status.value}: why"
        assert health.healthy is (status is HubStatus.REJECTED)


def test_a_rejection_of_another_controllers_command_does_not_make_ours_unhealthy() -> None:
    dog, _ = make()
    dog.hub_alive("pi-tool", True)
    # Before we command anything, a refused command cannot be ours.
    dog.state_received("nr", HubStatus.REJECTED, "command seq 1 from intruder refused: nr.run_c = 7 ...", None)
    assert dog.health("nr").healthy
    dog.command_sent("nr", 3)
    dog.state_received("nr", HubStatus.OK, "", 3)
    # Another controller's command is refused while the hub mirrors our newest one: reported, not unhealthy.
    dog.state_received("nr", HubStatus.REJECTED, "command seq 9 from intruder refused: nr.run_c = 7 ...", 3)
    health = dog.health("nr")
    assert health.healthy and health.reason == ""
    assert health.note == "hub reports rejected: command seq 9 from intruder refused: nr.run_c = 7 ..."
    # Our re-sent command is applied again: the status clears.
    dog.state_received("nr", HubStatus.OK, "", 3)
    assert dog.health("nr").healthy and dog.health("nr").note == ""


def test_a_standing_rejection_does_not_count_against_a_command_sent_after_it() -> None:
    dog, clock = make()
    dog.hub_alive("pi-tool", True)
    dog.command_sent("nr", 3)
    dog.state_received("nr", HubStatus.OK, "", 3)
    clock.now += 0.01
    dog.state_received("nr", HubStatus.REJECTED, "command seq 9 from intruder refused: ...", 3)
    clock.now += 0.01
    dog.command_sent("nr", 4)  # a change: until the hub applies it, its states still say rejected
    dog.state_received("nr", HubStatus.REJECTED, "command seq 9 from intruder refused: ...", 3)
    assert dog.health("nr").healthy and dog.health("nr").mirror_lag == 1
    dog.state_received("nr", HubStatus.OK, "", 4)
    assert dog.health("nr").healthy


def test_a_rejection_while_our_newest_command_is_not_mirrored_is_unhealthy_at_once() -> None:
    dog, _ = make()
    dog.hub_alive("pi-tool", True)
    dog.command_sent("nr", 3)
    dog.state_received("nr", HubStatus.OK, "", 3)
    dog.command_sent("nr", 4)
    # No need to wait for the bound:
    dog.state_received("nr", HubStatus.REJECTED, "command seq 4 from ctl-1 refused: ...", 3)
    health = dog.health("nr")
    assert not health.healthy and health.reason == "hub reports rejected: command seq 4 from ctl-1 refused: ..."
    dog.state_received("nr", HubStatus.OK, "", 4)
    assert dog.health("nr").healthy


def test_a_restarted_controller_counts_rejections_until_its_first_command_is_mirrored() -> None:
    dog, _ = make()
    dog.hub_alive("pi-tool", True)
    dog.command_sent("nr", 0)
    dog.reset_mirror("nr")  # the hub still mirrors the previous run's commands
    dog.state_received("nr", HubStatus.REJECTED, "command refused: ...", None)
    assert not dog.health("nr").healthy
    dog.state_received("nr", HubStatus.OK, "", 0)
    dog.state_received("nr", HubStatus.REJECTED, "command seq 5 from intruder refused: ...", 0)
    assert dog.health("nr").healthy
