"""Model-based tests of hubs (deploy/modeltest, DESIGN.md §9).

* The oracle and the checker on synthetic observations (no hub).
* Generated tests against a real hub process over Zenoh on loopback, emulating the
  reference station's nutrunner, lift and tool changer from the same model: they pass.
* The paper's finding: a nutrunner device whose torque-reached input resets only when
  run goes high again (tests/modeltest_station/quirky.py), tested against the paper's
  model, fails with the minimal sequence run_c := true, (settle), run_c := false and
  the expectation `nr.tqr_m := false` of `resetting`; against the corrected model
  (the reset in `starting`) the same device passes.
* `hubctl test` (as `python -m deploy.modeltest.cli test`): its refusals, a passing run.

Examples are few and the emulated devices run at speed 5 so that the file stays short;
the deadlines are functional bounds, never timing assertions.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.model import Model, Phase, Resource, ability, command, measured
from common.plumbing.lifecycle import free_port
from common.resources import nutrunner
from common.wire.keys import Keys, station_keys
from common.wire.messages import Codec
from deploy.modeltest import ModelTestFailed, Options, ResourceOracle, Target, model_based_test, run_model_test
from deploy.modeltest.checker import Checker, FindingKind, Observation, Violation
from deploy.modeltest.cli import Refused, select_resources
from deploy.modeltest.link import BusThread
from deploy.modeltest.runner import ModelTest
from deploy.modeltest.session import Source, Wait
from tests.hub_process import HubProcess, running_hub

pytest_plugins = ["deploy.modeltest.pytest_plugin"]

ROOT = Path(__file__).resolve().parent.parent
STATIONS = Path(__file__).resolve().parent / "modeltest_station"
EMULATED = STATIONS / "emulated.toml"
QUIRKY = STATIONS / "quirky.toml"
SPEED = "5"  # emulated effects take 0.05 s (nutrunner) to 0.12 s (lift)
STARTUP = 20.0  # generous bound for a process to start and connect on a loaded machine
FAST = Options(examples=6, max_steps=4, deadline=1.0, quiet=0.1)


def paper_model() -> Model:
    return Model("paper_nutrunner", (nutrunner("nr"),))


def corrected_model() -> Model:
    """The paper's nutrunner with the torque-reached reset moved from `resetting` to `starting`."""
    run_c = command("nr.run_c", initial=False)
    run_m, tqr_m, fail_m = measured("nr.run_m"), measured("nr.tqr_m"), measured("nr.fail_m")
    tighten = ability(
        "nr.tighten",
        enabled=Phase(~run_c & ~run_m, deliberate="nr.run_c := true"),
        starting=Phase(run_c & ~run_m, effects=[["nr.run_m := true", "nr.tqr_m := false"]]),
        executing=Phase(run_c & run_m & ~tqr_m & ~fail_m, effects=["nr.tqr_m := true", "nr.fail_m := true"]),
        finished=Phase(run_c & run_m & (tqr_m | fail_m), automatic="nr.run_c := false"),
        resetting=Phase(~run_c & run_m, effects=[["nr.run_m := false", "nr.fail_m := false"]]),
    )
    return Model("corrected_nutrunner", (Resource("nr", (run_c, run_m, tqr_m, fail_m), (tighten,),
                                                  device_type="nutrunner"),))


# --- the oracle and the checker, on synthetic observations --------------------------------------

def paper_checker(deadline: float = 0.5, lag: float = 0.01) -> Checker:
    return Checker(ResourceOracle(paper_model(), "nr"), deadline, lag)


def obs(time: float, run_m: bool, tqr_m: bool, fail_m: bool, run_c: bool) -> Observation:
    return Observation(time, (run_m, tqr_m, fail_m), (run_c,))


def test_an_outcome_seen_in_parts_must_complete_within_the_deadline() -> None:
    checker = paper_checker()
    checker.start(obs(0.0, True, True, False, True))
    checker.observe(obs(0.10, True, True, False, False))  # the hub applied run_c := false
    checker.observe(obs(0.20, False, True, False, False))  # run_m fell, tqr_m still true: in flight
    checker.observe(obs(0.30, False, True, False, False))
    assert not checker.quiescent
    with pytest.raises(Violation) as caught:
        checker.check_time(0.9)
    finding = caught.value.finding
    assert finding.kind is FindingKind.EFFECT_NOT_OBSERVED
    assert (finding.effect, finding.guard, finding.expected) == (
        "nr.tighten.resetting", "!nr.run_c && nr.run_m", ("nr.tqr_m := false",))
    assert "nr.tqr_m=true" in finding.observed


def test_an_outcome_seen_in_parts_passes_when_it_completes() -> None:
    checker = paper_checker()
    checker.start(obs(0.0, True, True, False, False))
    checker.observe(obs(0.10, False, True, False, False))
    checker.observe(obs(0.20, False, False, False, False))
    checker.check_time(2.0)
    assert checker.quiescent


def test_an_enabled_effect_must_show_an_outcome() -> None:
    checker = paper_checker()
    checker.start(obs(0.0, False, False, False, True))  # starting: run_m := true is expected
    checker.observe(obs(0.3, False, False, False, True))
    with pytest.raises(Violation) as caught:
        checker.check_time(0.6)
    assert caught.value.finding.effect == "nr.tighten.starting"
    assert caught.value.finding.expected == ("nr.run_m := true",)


def test_a_command_change_withdraws_the_expectation() -> None:
    checker = paper_checker()
    checker.start(obs(0.0, False, False, False, True))
    checker.observe(obs(0.3, False, False, False, False))  # run_c back to false before the device started
    checker.check_time(2.0)
    assert checker.quiescent


def test_a_change_no_effect_allows_is_reported_with_what_was_enabled() -> None:
    checker = paper_checker()
    checker.start(obs(0.0, False, False, False, False))
    with pytest.raises(Violation) as caught:
        checker.observe(obs(0.1, False, True, False, False))
        checker.check_time(0.2)
    finding = caught.value.finding
    assert finding.kind is FindingKind.UNEXPLAINED_CHANGE
    assert "nr.tqr_m: false -> true" in finding.message
    assert "no effect of nr is enabled" in finding.details[0]


def test_effects_may_fire_under_a_command_that_a_stale_sample_still_shows() -> None:
    # The hub publishes a new mirror with the values it read before applying it: tqr_m,
    # reached under run_c = true, shows one sample after the mirror says run_c = false.
    samples = [obs(0.00, True, False, False, True), obs(0.02, True, False, False, False),
               obs(0.04, True, True, False, False), obs(0.06, False, False, False, False)]
    checker = paper_checker(lag=0.06)
    checker.start(samples[0])
    for sample in samples[1:]:
        checker.observe(sample)
    checker.check_time(0.5)
    assert checker.quiescent
    strict = paper_checker(lag=0.001)
    strict.start(samples[0])
    with pytest.raises(Violation):
        for sample in samples[1:]:
            strict.observe(sample)
        strict.check_time(0.5)


def test_reachable_states_and_the_models_commands() -> None:
    oracle = ResourceOracle(paper_model(), "nr")
    assert oracle.reachable_measured == {(False, False, False), (True, False, False), (True, True, False),
                                         (True, False, True)}
    assert not oracle.is_reachable((False, True, False))  # the quirky device at rest after a tightening
    assert ResourceOracle(corrected_model(), "nr").is_reachable((False, True, False))
    assert oracle.model_commands((False, False, False), (False,)) == [{"run_c": True}]  # enabled: deliberate
    assert oracle.model_commands((True, True, False), (True,)) == [{"run_c": False}]  # finished: automatic
    assert oracle.model_commands((True, False, False), (True,)) == []


def test_the_tool_changer_follows_the_robot_and_the_dock_as_context() -> None:
    _, model = load_station(EMULATED)
    oracle = ResourceOracle(model, "rsp")
    assert "ur.pos_m" in oracle.context and "dock.nutrunner_home_m" in oracle.context
    at_rest = oracle.env_of({"rsp.lock_c": True}, {})
    assert [e.name for e in oracle.enabled((False, "none", True), at_rest)] == ["rsp.lock.starting.effect"]
    at_dock = oracle.env_of({"rsp.lock_c": True}, {"ur.pos_m": "dock_nutrunner"})
    assert [e.name for e in oracle.enabled((False, "none", True), at_dock)] == ["rsp.lock.pick_up_nutrunner"]


# --- which resources `hubctl test` may test ------------------------------------------------------

def test_resource_selection_and_its_refusals() -> None:
    config, model = load_station(EMULATED)
    assert select_resources(config, model, "tool", None, False).resources == ["nr", "lift", "rsp"]
    assert select_resources(config, model, "tool", None, True).resources == ["nr", "lift", "rsp"]
    with pytest.raises(Refused, match=r"ur is marked unsafe_for_random_commands.*--allow-motion.*--resource agv"):
        select_resources(config, model, "rest", None, False)
    with pytest.raises(Refused, match=r"--allow-motion refused: hub rest has devices in 'real' mode: ur"):
        select_resources(config, model, "rest", ["ur"], True)
    with pytest.raises(Refused, match=r"resource 'ur' is not served by hub 'tool' \(it is served by hub 'rest'"):
        select_resources(config, model, "tool", ["ur"], False)
    with pytest.raises(Refused, match=r"no resource with command variables"):
        select_resources(config, model, "rest", ["dock", "cam"], False)
    chosen = select_resources(config, model, "rest", ["agv", "rfid"], False)
    assert chosen.resources == ["agv"] and "rfid: skipped" in chosen.notes[0]
    with pytest.raises(Refused, match=r"no hub named 'nope'"):
        select_resources(config, model, "nope", None, False)


# --- generated tests against an emulated hub of the same model: they pass ----------------------

EMULATED_PORT = free_port()


@pytest.fixture(scope="module")
def emulated_hub(tmp_path_factory: pytest.TempPathFactory) -> Iterator[HubProcess]:
    log = tmp_path_factory.mktemp("modeltest") / "tool.log"
    with running_hub(EMULATED, "tool", EMULATED_PORT, log, "--speed", SPEED) as hub:
        yield hub


def emulated_target() -> Target:
    return Target.from_config(EMULATED, loopback_port=EMULATED_PORT)


def against_the_emulated_hub(test: Callable[[], None]) -> Callable[[], None]:
    return pytest.mark.slow(pytest.mark.usefixtures("emulated_hub")(test))


test_emulated_nutrunner = against_the_emulated_hub(model_based_test("nr", emulated_target, FAST))
test_emulated_lift = against_the_emulated_hub(model_based_test("lift", emulated_target, FAST))
test_emulated_tool_changer = against_the_emulated_hub(model_based_test("rsp", emulated_target, FAST))


@pytest.mark.slow
@pytest.mark.usefixtures("emulated_hub")
def test_a_controller_that_starts_commanding_during_the_test_stops_it() -> None:
    target = emulated_target()
    codec, keys, bus = Codec(target.model.resource_by_name["nr"]), station_keys(target.station), target.bus()
    stop = threading.Event()

    def command_after_a_second() -> None:
        time.sleep(1.0)
        seq = 0
        while not stop.is_set():
            seq += 1
            payload = codec.encode_command(codec.command({"run_c": False}, seq=seq, controller="decs-87654321"))
            bus.call_soon(lambda p=payload: bus.bus.publish(keys.cmd("nr"), p))
            time.sleep(0.1)

    sender = threading.Thread(target=command_after_a_second, daemon=True)
    sender.start()
    try:
        report = run_model_test(target, "nr", Options(examples=100, deadline=1.0, quiet=0.1), say=lambda _: None)
    finally:
        stop.set()
        sender.join(5)
    assert report.aborted is not None and "another controller (decs-87654321)" in report.aborted
    assert "two controllers would fight" in report.describe()


# --- the paper's finding --------------------------------------------------------------------------

QUIRKY_PORT = free_port()
# The deadline leaves room for a loaded machine (3 test workers on 2 cores): at 0.6 s a shrinking run once saw
# the hub mirror a command too late, and called it "command not mirrored" instead of the missing effect.
QUIRKY_OPTIONS = Options(examples=8, max_steps=4, deadline=1.5, quiet=0.1)


@pytest.fixture
def quirky_hub(hub_process: Callable[..., HubProcess]) -> HubProcess:
    """A fresh hub emulating the quirky nutrunner (each test starts with a device never used)."""
    return hub_process(QUIRKY, "tool", QUIRKY_PORT, "--speed", SPEED)


@pytest.mark.slow
def test_the_papers_model_fails_on_the_real_nutrunner_with_a_minimal_sequence(quirky_hub: HubProcess,
                                                                              model_test: ModelTest) -> None:
    target = Target.from_config(QUIRKY, loopback_port=QUIRKY_PORT, model=paper_model())
    report = model_test(target, "nr", QUIRKY_OPTIONS, reset=quirky_hub.restart, expect_pass=False)
    assert report.aborted is None, report.aborted
    assert not report.passed and report.failure is not None and report.shrunk, report.describe()
    failure = report.failure
    # run_c := true, wait for torque, run_c := false (the example's way home) -> tqr_m := false never comes
    assert [step.command for step in failure.steps] == [{"run_c": True}, {"run_c": False}], report.describe()
    assert [step.wait for step in failure.steps] == [Wait.SETTLE, Wait.SETTLE]
    assert failure.steps[0].source is Source.MODEL and failure.steps[1].source is Source.HOME
    assert failure.failed_at == 2
    assert failure.finding.kind is FindingKind.EFFECT_NOT_OBSERVED
    assert failure.finding.effect == "nr.tighten.resetting"
    assert failure.finding.guard == "!nr.run_c && nr.run_m"
    assert failure.finding.expected == ("nr.tqr_m := false",)
    assert "nr.tqr_m=true" in failure.finding.observed
    text = report.describe()
    assert "nr.tighten.resetting: !nr.run_c && nr.run_m  expected  nr.tqr_m := false" in text
    assert "minimal failing command sequence" in text


@pytest.mark.slow
def test_the_corrected_model_passes_on_the_same_device(quirky_hub: HubProcess, model_test: ModelTest) -> None:
    target = Target.from_config(QUIRKY, loopback_port=QUIRKY_PORT, model=corrected_model())
    report = model_test(target, "nr", QUIRKY_OPTIONS)
    assert report.passed and report.examples >= QUIRKY_OPTIONS.examples - 1


@pytest.mark.slow
def test_a_failed_generated_test_fails_the_pytest_test_with_its_report(quirky_hub: HubProcess) -> None:
    target = Target.from_config(QUIRKY, loopback_port=QUIRKY_PORT, model=paper_model())
    test = model_based_test("nr", target, Options(examples=2, max_steps=2, deadline=0.6, quiet=0.1))
    with pytest.raises(ModelTestFailed, match=r"expected  nr.tqr_m := false") as caught:
        test()
    assert "not shrunk" in str(caught.value)  # no reset given: the device stays out of its model


# --- hubctl test ------------------------------------------------------------------------------------

def hubctl_test(*args: str, timeout: float = 90.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "deploy.modeltest.cli", "test", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_hubctl_test_refuses_the_robot_without_allow_motion() -> None:
    result = hubctl_test("rest", "--config", str(EMULATED), "--resource", "ur")
    assert result.returncode == 2, result.stdout + result.stderr
    assert "unsafe_for_random_commands" in result.stdout and "--allow-motion" in result.stdout


def test_hubctl_test_refuses_allow_motion_on_a_hub_with_real_devices() -> None:
    result = hubctl_test("rest", "--config", str(EMULATED), "--resource", "ur", "--allow-motion")
    assert result.returncode == 2, result.stdout + result.stderr
    assert "'real' mode" in result.stdout and "ur" in result.stdout


def test_hubctl_test_refuses_while_a_controller_commands_the_hub() -> None:
    port = free_port()
    config = zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"])  # a controller connecting to the test
    config.insert_json5("connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 100,
                                                     "period_increase_factor": 1}))
    fake = BusThread(config, description="fake controller").start()
    _, model = load_station(EMULATED)
    codec, keys = Codec(model.resource_by_name["nr"]), Keys("modeltest")
    stop = threading.Event()

    def command_at_10_hz() -> None:
        seq = 0
        while not stop.is_set():
            seq += 1
            payload = codec.encode_command(codec.command({"run_c": False}, seq=seq, controller="decs-12345678"))
            fake.call_soon(lambda p=payload: fake.bus.publish(keys.cmd("nr"), p))
            time.sleep(0.1)

    sender = threading.Thread(target=command_at_10_hz, daemon=True)
    sender.start()
    try:
        result = hubctl_test("tool", "--config", str(EMULATED), "--loopback-port", str(port))
    finally:
        stop.set()
        sender.join(5)
        fake.close()
    assert result.returncode == 2, result.stdout + result.stderr
    assert "a controller is running" in result.stdout and "decs-12345678 commanding nr" in result.stdout


@pytest.mark.slow
def test_hubctl_test_passes_an_emulated_hub(hub_process: Callable[..., HubProcess]) -> None:
    port = free_port()
    hub_process(EMULATED, "tool", port, "--speed", SPEED)
    result = hubctl_test("tool", "--config", str(EMULATED), "--resource", "nr", "--examples", "3",
                         "--max-steps", "3", "--deadline", "1", "--loopback-port", str(port))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "nr: example 3/3" in result.stdout and "PASSED 3 examples" in result.stdout
