"""Fault tests of the running station: real processes, real Zenoh on loopback (DESIGN.md §6, §7, §9).

The station is tests/fault_station: a robot, a nutrunner and 4 bolts, emulated, planned
in milliseconds. Each test starts the controller and the two hubs (`pi-tool` serving
`nr`, `ur10` serving `ur`) as their own processes, records every command, state,
status and state snapshot with a watcher in this process (`harness.Station`), injects
one fault and then checks what happened against these streams and the controller's
SQLite file.

"Tightened exactly once" is checked on what the devices did, not only on what the
controller believes: in the nutrunner hub's state stream (every state, 50 Hz) each
rising edge of `nr.tqr_m` is one tightening, done at the pose the robot hub reports at
that moment (the model forbids the robot to move while the nutrunner runs). Every bolt
pose must see exactly one, and the controller's view must agree: each bolt variable
goes `placed -> tightened` once in the snapshots and stays, each `TightenBolt<i>`
finishes once and stays finished, and the persisted state says the same.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from common.model import OperationState
from common.wire.messages import HubStatus
from tests.fault_station.checks import (
    POSE_OF,
    RUN_TIMEOUT_S,
    assert_station_done_each_bolt_once,
    between,
    controller_commands,
    nr_running_on_bolt,
    op_states,
    tightenings,
)
from tests.fault_station.garbage import flood, message_samples, mirror_key, payload_strategy, with_changes
from tests.fault_station.harness import Station
from tests.fault_station.model import BOLTS, bolt
from tests.fault_station.watcher import Seen, rising_edges, value_at

pytestmark = pytest.mark.timeout(120)

DETECTION_BOUND_S = 2.0  # the bound for noticing a frozen hub
DETECTION_MARGIN_S = 0.5


@pytest.fixture
def station(tmp_path: Path) -> Iterator[Station]:
    with Station(tmp_path) as s:
        yield s


# --- 1. kill -9 the nutrunner's hub while it tightens, restart it --------------------------------

@pytest.mark.slow
def test_nutrunner_hub_killed_mid_tightening_restarts_and_each_bolt_is_tightened_once(station: Station) -> None:
    station.start()
    nr_running_on_bolt(station, 2)  # one bolt done, the second under way
    killed_at = station.kill("pi-tool")
    last = [s for s in station.watch.states("nr") if s.at <= killed_at][-1].message
    assert last.run_m and not last.tqr_m, f"not killed mid-tightening: {last}"
    interrupted = POSE_OF[value_at(station.watch.states("ur"), "pos_m", killed_at)]

    # The controller sees the hub go (its TCP link closes: the token vanishes at once) ...
    station.wait_for(lambda: (h := station.watch.health("nr")) is not None and "not alive" in h.reason, 5,
                     "nr reported unhealthy: hub not alive")
    assert station.watch.snapshot().get(bolt(interrupted)) != "tightened"
    # ... and the restarted hub (stateless, safe state at boot) takes the re-sent command and finishes.
    station.start_hub("pi-tool")
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes after the hub restart")

    assert_station_done_each_bolt_once(station)
    (edge,) = [e for i, e in tightenings(station) if i == interrupted]
    assert edge.at > killed_at, "the interrupted bolt was tightened by the restarted hub"
    # The nutrunner ran 4 times plus the interrupted run, no more.
    assert len(rising_edges(station.watch.states("nr"), "run_m")) == len(BOLTS) + 1


# --- 2. kill -9 the controller mid-run, restart it on the same database -----------------------

@pytest.mark.slow
def test_controller_killed_mid_run_resumes_from_its_database_and_redoes_nothing(station: Station) -> None:
    station.start()
    first_controller = station.wait_for(station.watch.status, 5, "a status").controller

    def between_bolts() -> bool:  # >= 1 bolt done (and reported), the nutrunner idle, the robot on its way
        states = station.watch.states("nr")
        last = states[-1].message if states else None
        status = station.watch.status()
        return last is not None and not last.run_m and not last.tqr_m \
            and 1 <= len(rising_edges(states, "tqr_m")) < len(BOLTS) \
            and status is not None and OperationState.FINISHED in op_states(status).values()

    station.wait_for(between_bolts, RUN_TIMEOUT_S, "a bolt done and the nutrunner idle", poll=0.002)
    killed_at = station.kill("controller")
    before = station.watch.status()
    assert before is not None and before.controller == first_controller and not before.finished
    finished_before = {name for name, state in op_states(before).items() if state == OperationState.FINISHED}
    assert finished_before, f"no operation finished before the kill: {op_states(before)}"
    # Nothing reported finished is lost: the database holds it (written before it is published).
    persisted = station.persisted()
    for name in finished_before:
        assert persisted[f"op.{name}"] == OperationState.FINISHED
    # What the killed controller had recorded (its database, not the 1 Hz snapshot, which may lag).
    tightened_before = {i for i in BOLTS if persisted.get(bolt(i)) == "tightened"}
    assert all(persisted[bolt(i)] == "tightened" for i in BOLTS
               if station.watch.snapshot().get(bolt(i)) == "tightened")

    station.start_controller(fresh=False)
    station.wait_for(lambda: (s := station.watch.status()) is not None and s.controller != first_controller, 15,
                     "a status from the restarted controller")
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes after the controller restart")

    assert_station_done_each_bolt_once(station)
    second = [s.message for s in station.watch.statuses() if s.message.controller != first_controller]
    # Restored, not redone: from its first status on, what was finished stays finished.
    for status in second:
        states = op_states(status)
        assert all(states[name] == OperationState.FINISHED for name in finished_before), states
    # The command state came from the hubs' mirrors: the new controller's first command to each hub (seq 0,
    # as the hub mirrored it) is what the hub had applied last from the old one (the robot is not sent back).
    for resource, codec in station.watch.codecs.items():
        mirrors = [s.message.mirror for s in station.watch.states(resource) if s.message.mirror is not None]
        old = [m for m in mirrors if m.controller == first_controller][-1]
        new = next(m for m in mirrors if m.controller == second[0].controller and m.seq == 0)
        assert codec.values(new) == codec.values(old), f"{resource}: {codec.values(old)} -> {codec.values(new)}"
    # The nutrunner ran exactly once per bolt in total: no bolt was tightened again after the restart.
    assert len(rising_edges(station.watch.states("nr"), "run_m")) == len(BOLTS)
    assert all(edge.at > killed_at for i, edge in tightenings(station) if i not in tightened_before)


# --- 3. SIGSTOP a hub: unhealthy within 2 s, nothing depending on it moves, resumes on SIGCONT ----------

@pytest.mark.slow
def test_frozen_hub_is_unhealthy_within_2_s_nothing_depending_on_it_is_commanded_and_control_resumes(
        station: Station) -> None:
    station.start()
    nr_running_on_bolt(station, 2)
    frozen_at = station.freeze("pi-tool")
    at_bolt = value_at(station.watch.states("ur"), "pos_m", frozen_at)
    assert at_bolt in POSE_OF, f"the robot is at {at_bolt}, not at a bolt"
    before = station.watch.status()
    assert before is not None

    def nr_unhealthy_status() -> Seen | None:
        return next((s for s in station.watch.statuses() if s.at > frozen_at
                     and not next(h for h in s.message.health if h.resource == "nr").healthy), None)

    detected = station.wait_for(nr_unhealthy_status, DETECTION_BOUND_S + 3.0, "nr reported unhealthy")
    delay = detected.at - frozen_at
    reason = next(h for h in detected.message.health if h.resource == "nr").reason
    assert delay <= DETECTION_BOUND_S + DETECTION_MARGIN_S, f"frozen hub reported after {delay:.2f} s"
    assert "stale" in reason or "not alive" in reason, reason
    assert next(h for h in detected.message.health if h.resource == "ur").healthy
    # Stay frozen a while longer, then let it go.
    time.sleep(1.5)
    thawed_at = station.thaw("pi-tool")

    # While frozen the controller kept sending (10 Hz), and nothing that needs the nutrunner changed:
    # the robot stays commanded to the bolt it is at (it is not sent on to the next bolt, whose
    # tightening needs the nutrunner) and stays there; the nutrunner's own command is held; no bolt
    # and no operation is counted as done.
    ur_sent = between(controller_commands(station, "ur"), frozen_at, thawed_at)
    nr_sent = between(controller_commands(station, "nr"), frozen_at, thawed_at)
    window = thawed_at - frozen_at
    assert len(ur_sent) >= 5 * window and len(nr_sent) >= 5 * window, "the controller stopped sending"
    assert {c.message.ref_pos_c for c in ur_sent} == {at_bolt}
    assert {c.message.run_c for c in nr_sent} == {True}
    assert {s.message.pos_m for s in between(station.watch.states("ur"), frozen_at, thawed_at)} == {at_bolt}
    for s in between(station.watch.snapshots(), frozen_at, thawed_at):
        assert s.message.values[bolt(POSE_OF[at_bolt])] == "placed"
    finished_before = {name for name, state in op_states(before).items() if state == OperationState.FINISHED}
    for s in between(station.watch.statuses(), frozen_at, thawed_at):
        # The unfinished ones keep executing, or wait in `error` (no plan without the nutrunner), to be retried.
        for op in s.message.operations:
            finished = op.state == OperationState.FINISHED
            assert finished == (op.name in finished_before), f"{op.name} is {op.state} while frozen"
            assert op.state != OperationState.ERROR or "nr" in op.error, op.error
    for s in between(station.watch.statuses(), detected.at, thawed_at):
        assert not next(h for h in s.message.health if h.resource == "nr").healthy, "nr reported healthy while frozen"

    # After SIGCONT the hub reconnects by itself, nr is healthy again, control resumes, the station finishes.
    station.wait_for(lambda: (h := station.watch.health("nr")) is not None and h.healthy, 15,
                     "nr healthy again after SIGCONT")
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes after SIGCONT")
    assert_station_done_each_bolt_once(station)


def test_a_result_that_arrives_while_another_resource_is_unhealthy_is_recorded_once() -> None:
    """The engine side of an unhealthy hub at the moment a tightening ends (found by test 5: a robot hub
    briefly unhealthy while the nutrunner reached torque made the bolt be tightened twice).

    The nutrunner is healthy and resets itself (its automatic `run_c := false`); the tracking that
    records the bolt reads the robot's last known pose. Held back with the robot, the observation
    would be lost once the nutrunner reset, and the bolt tightened again."""
    from controller.engine import Engine
    from controller.stack import build_controller_stack
    from tests.fault_station.model import build_model

    compiled = build_controller_stack(build_model()).compiled
    torque = compiled.with_values(compiled.initial(), {"ur.ref_pos_c": "at_bolt1", "ur.pos_m": "at_bolt1",
                                                       "nr.run_c": True, "nr.run_m": True, "nr.tqr_m": True})
    for unhealthy, run_c in ((set(), False), ({"ur"}, False), ({"nr"}, True), ({"nr", "ur"}, True)):
        tick = Engine(compiled).tick(torque, disabled=frozenset(unhealthy))
        after = compiled.unpack(tick.state)
        assert after[bolt(1)] == "tightened", f"unhealthy {unhealthy}: {tick.fired}"
        assert after["nr.run_c"] is run_c, f"an unhealthy nutrunner gets no command change ({unhealthy})"
        assert tick.fired.count("engine.bolt1_tightened") == 1


# --- 4. a hub that receives commands but does not apply them ----------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("applies", [1, 0], ids=["stale-mirror", "no-mirror"])
def test_hub_that_does_not_apply_commands_is_reported_by_its_mirror_lag(station: Station, applies: int) -> None:
    """pi-tool is tests/fault_station/lazy_hub.py: it applies the first `applies` commands it receives and
    none after, yet stays alive, fresh and `ok`. Only its mirror tells."""
    bound = station.config.controller.mirror_timeout_s
    station.start(lazy={"pi-tool": applies})
    station.wait_for(lambda: any(s.message.status == HubStatus.OK for s in station.watch.states("nr")), 20,
                     "the lazy hub receives commands")
    mirrors = {s.message.mirror.seq for s in station.watch.states("nr") if s.message.mirror is not None}
    assert len(mirrors) == applies, f"mirrored {mirrors}"
    # The first command it did not apply, as the controller published it.
    sent = station.wait_for(lambda: next((c for c in controller_commands(station, "nr")
                                          if c.message.seq > max(mirrors, default=-1)), None),
                            RUN_TIMEOUT_S, "a command the lazy hub does not apply")

    def lag_reported() -> Seen | None:
        for s in station.watch.statuses():
            h = next(h for h in s.message.health if h.resource == "nr")
            if s.at > sent.at and not h.healthy:
                return s
        return None

    reported = station.wait_for(lag_reported, bound + 3.0, "nr reported unhealthy")
    health = next(h for h in reported.message.health if h.resource == "nr")
    # On the controller's own clock (the command's and the status's time stamps): when the watcher received
    # each of them says as much about this machine's load as about the watchdog.
    delay = reported.message.time - sent.message.time
    assert health.reason.startswith(f"mirror lags: command seq {sent.message.seq} "), health.reason
    assert health.mirror_lag >= 1
    # Within the bound plus one status period and scheduling, and not before the bound.
    assert bound <= delay <= bound + 0.75, f"mirror lag reported {delay:.2f} s after the command (bound {bound} s)"
    # Only the mirror shows it: the lazy hub is alive, fresh, says ok, and never ran the nutrunner.
    lazy_states = station.watch.states("nr")
    assert {s.message.mirror.seq for s in lazy_states if s.message.mirror is not None} == mirrors
    statuses = [s.message.status for s in lazy_states]
    # Once it got a command it says ok, or `safe_state` while no command reaches it, and ok again with the
    # next one. A controller starved on a loaded machine is silence, and a hub must then drive its safe
    # state: seen twice, the controller stalled 1.4-1.5 s around its first plan and the hubs lost its
    # liveliness (1 s lease) just before their safe state. The watcher cannot tell what reached the hub
    # (in one of those runs it saw commands every 0.1 s that the hub, the controller's token gone, rightly
    # did not take), so that a hub drops to its safe state only on silence is tested where it can be,
    # in tests/test_hub_runtime.py (not its own stalls, not commands its device could not take).
    sent_at = [c.at for c in controller_commands(station, "nr")]
    gap = max((b - a for a, b in itertools.pairwise(sent_at)), default=0.0)
    first_ok = statuses.index(HubStatus.OK)
    assert set(statuses[first_ok:]) <= {HubStatus.OK, HubStatus.SAFE_STATE}, (
        f"statuses {_changes(statuses)}; longest gap between the controller's commands {gap:.2f} s")
    station.wait_for(lambda: station.watch.states("nr")[-1].message.status == HubStatus.OK, 5.0,
                     "the lazy hub says ok with the next command")
    assert not any(s.message.run_m for s in lazy_states)
    assert health.age is not None and health.age < station.config.controller.stale_after_s

    # It stays reported, and nothing that needs the nutrunner goes on (no bolt is done).
    time.sleep(1.0)
    health = station.watch.health("nr")
    assert not health.healthy and health.reason.startswith("mirror lags"), health.reason
    assert all(s.message.values[bolt(i)] == "placed" for s in station.watch.snapshots() for i in BOLTS)

    # Replace the faulty hub by a good one: control resumes without restarting anything else.
    controller = station.processes["controller"].popen
    station.kill("pi-tool")
    station.start_hub("pi-tool")
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes with a working pi-tool")
    assert controller is not None and station.processes["controller"].popen is controller and controller.poll() is None
    assert_station_done_each_bolt_once(station)


def _changes(statuses: list[HubStatus]) -> list[str]:
    return [str(s) for i, s in enumerate(statuses) if i == 0 or statuses[i - 1] != s]


def test_mirror_lag_is_measured_from_the_oldest_command_not_mirrored() -> None:
    """The watchdog side of test 4: a hub that applies nothing is reported one bound after the first
    command it did not mirror, even while the controller keeps changing the command (each change must
    not restart the clock), and even when that first command is seq 0; a hub that applies every
    command within the bound is never reported, however often the command changes."""
    from controller.watchdog import Watchdog

    now = [0.0]
    lazy = Watchdog({"nr": "pi-tool"}, mirror_bound=1.0, clock=lambda: now[0])
    lazy.hub_alive("pi-tool", True)
    for seq in range(6):  # a new command every 0.4 s, none mirrored
        lazy.command_sent("nr", seq)
        lazy.state_received("nr", HubStatus.OK, "", None)
        reason = lazy.health("nr").reason
        assert (reason == "") == (now[0] <= 1.0), f"at {now[0]:.1f} s: {reason!r}"
        now[0] += 0.4
    assert reason.startswith("mirror lags: command seq 0 sent 2.00 s ago")

    now[0] = 0.0
    prompt = Watchdog({"nr": "pi-tool"}, mirror_bound=1.0, clock=lambda: now[0])
    prompt.hub_alive("pi-tool", True)
    for seq in range(20):  # a new command every 0.4 s, each mirrored 0.8 s after it was sent
        prompt.command_sent("nr", seq)
        prompt.state_received("nr", HubStatus.OK, "", seq - 2 if seq >= 2 else None)
        assert prompt.health("nr").healthy, prompt.health("nr").reason
        now[0] += 0.4


# --- 5. garbage, truncated, wrong-schema and out-of-domain payloads on every key ------------------

@pytest.mark.slow
def test_garbage_on_every_key_changes_nothing_and_stops_nothing(station: Station) -> None:
    station.start()
    nr_running_on_bolt(station, 1)
    strategy = payload_strategy(station)

    # While the station works: it shrugs the garbage off and finishes, each bolt once.
    flood(station, strategy, examples=60, spacing=0.03)
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes under garbage")
    assert_station_done_each_bolt_once(station)

    # At rest, so that any change shows: the baseline of commands, mirrors and outputs.
    station.wait_for(lambda: (s := station.watch.state("nr")) is not None and not s.run_m and station.all_healthy(),
                     10, "the station at rest")
    time.sleep(0.5)
    start = time.monotonic()
    codecs = station.watch.codecs
    baseline_cmd = {r: controller_commands(station, r)[-1].message for r in codecs}
    baseline_state = {r: station.watch.state(r) for r in codecs}
    persisted = station.persisted()
    ops = op_states(station.watch.current_status())

    published = flood(station, strategy, examples=100, spacing=0.01)
    # Out-of-domain commands for each resource in the holder's name (another's are not even decoded),
    # deterministically: the hub rejects them and says so.
    holder = {"controller": baseline_cmd["nr"].controller, "epoch": baseline_cmd["nr"].epoch}

    def rejection(resource: str, sent_at: float, shown: str) -> Callable[[], Any]:
        # Any: a state struct is generated from its resource's model; its fields have no static type.
        return lambda: next((s.message for s in station.watch.states(resource) if s.at > sent_at
                             and s.message.status == HubStatus.REJECTED and shown in s.message.detail), None)

    for resource, raw, shown in (
            ("nr", with_changes(message_samples(station)["cmd"][0], run_c=7, seq=10**6, **holder), "nr.run_c = 7 "),
            ("ur", with_changes(message_samples(station)["cmd"][1], ref_pos_c="on_the_moon", seq=10**6, **holder),
             "ur.ref_pos_c = 'on_the_moon' ")):
        sent_at = time.monotonic()
        station.watch.publish(station.keys.cmd(resource), raw)
        rejected = station.wait_for(rejection(resource, sent_at, shown), 3,
                                    f"{resource} rejects an out-of-domain command")
        assert "outside its domain" in rejected.detail
        codec = codecs[resource]
        assert mirror_key(rejected.mirror, codec) == mirror_key(baseline_state[resource].mirror, codec)
        assert codec.values(rejected) == codec.values(baseline_state[resource])
    time.sleep(0.5)
    end = time.monotonic()
    station.wait_for(station.all_healthy, 5, "every resource healthy again (the controller's re-sent commands)")

    assert published == 100
    # Every process is up and declared alive.
    assert not station.dead() and all(p.alive() for p in station.processes.values())
    assert station.watch.alive_hubs() == set(station.config.hubs)
    # The controller's commands did not change (values and seq) while garbage arrived, ...
    for resource, codec in codecs.items():
        sent = between(controller_commands(station, resource), start, end)
        assert len(sent) >= 5 * (end - start), f"{resource}: the controller stopped re-sending"
        assert {(c.message.controller, c.message.seq, tuple(codec.values(c.message).items())) for c in sent} \
            == {(baseline_cmd[resource].controller, baseline_cmd[resource].seq,
                 tuple(codec.values(baseline_cmd[resource]).items()))}, f"{resource} commands changed"
        # ... nor the hubs' mirrors and outputs (every state they published, rejected ones included) ...
        states = between(station.watch.states(resource), start, end)
        assert len(states) >= 25 * (end - start), f"{resource}: the hub stopped publishing"
        assert {mirror_key(s.message.mirror, codec) for s in states} == \
            {mirror_key(baseline_state[resource].mirror, codec)}, f"{resource} mirror changed"
        assert {tuple(codec.values(s.message).items()) for s in states} == \
            {tuple(codec.values(baseline_state[resource]).items())}, f"{resource} outputs changed"
        assert any(s.message.status == HubStatus.REJECTED for s in states), f"{resource} rejected nothing"
    # ... nor the controller's state.
    assert station.persisted() == persisted
    assert op_states(station.watch.current_status()) == ops and station.watch.finished()
    # The garbage did arrive (the watcher, on the same keys, could not decode it either) and was logged.
    assert sum(station.watch.undecodable().values()) >= published // 2
    hub_log = station.processes["pi-tool"].tail(10**7)
    assert "rejected command" in hub_log and "dropped malformed command" in hub_log
    assert "dropped state" in station.processes["controller"].tail(10**7)
