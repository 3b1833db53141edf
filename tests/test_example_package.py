"""A station outside the core (issue 11): examples/pick_cell, installed into the venv as a package of its own.

* The package installs (`pip install -e examples/pick_cell`, once per session) and its
  entry points give statehub the driver and the simulator of its own device type
  (`vacuum_ejector`); its other own type (`box_feeder`) has neither and stays emulated.
* The ejector's simulator (physics on a fake clock) and its driver against the simulator
  served in-process over Modbus TCP: commands, readings, blow-off, self-test.
* The model-based test of the ejector's hub (deploy/modeltest), its driver against the
  simulator process: the model, the driver and the simulator agree.
* `hubctl up --config examples/pick_cell/hubs.toml` runs it to completion as separate
  processes over Zenoh, emulated and with `--mode sim` (the ejector's driver against its
  simulator process); and a station whose device types are all unknown to statehub
  (tests/custom_station) runs to completion through `hubctl up` too.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import pytest

from deploy.modeltest import Options
from hubs.drivers.base import DeviceUnavailable
from hubs.drivers.registry import find_driver
from hubs.sim.registry import find_simulator, host_port
from tests.scaffold_support import venv_lock

if TYPE_CHECKING:
    from deploy.scaffold.testing import ModelTest, StationHubs

pytest_plugins = ["deploy.modeltest.pytest_plugin", "deploy.scaffold.testing"]

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "examples" / "pick_cell"
CONFIG = PACKAGE / "hubs.toml"
DISTRIBUTION = "statehub-pick-cell"
HUBCTL = Path(sys.executable).parent / "hubctl"
DEADLINE_S = 5.0  # a functional bound for the simulated ejector to react, not a timing claim


def _installed_here() -> bool:
    try:
        dist = metadata.distribution(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return False
    points = {(p.group, p.name) for p in dist.entry_points}
    direct_url = dist.read_text("direct_url.json") or ""
    return {("statehub.drivers", "vacuum_ejector"), ("statehub.simulators", "vacuum_ejector")} <= points and \
        PACKAGE.as_uri() in direct_url


@pytest.fixture(scope="session")
def pick_cell() -> Iterator[None]:
    """The example package installed (editable) into this venv; it stays installed (`./dev up` can run it)."""
    with venv_lock():
        if not _installed_here():
            subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                            "--no-deps", "--no-build-isolation", "-e", str(PACKAGE)], check=True, capture_output=True)
    # .pth files are read at start-up: this process imports it from the source; subprocesses as installed.
    sys.path.insert(0, str(PACKAGE))
    try:
        yield
    finally:
        sys.path.remove(str(PACKAGE))


def hubctl(*args: str, cwd: Path = ROOT, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # the test stations' models live in tests/
    return subprocess.run([str(HUBCTL), *args], cwd=cwd, env=env, text=True, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, timeout=timeout, check=False)


# --- the package and its entry points -----------------------------------------------------------

def test_the_package_gives_statehub_its_driver_and_simulator(pick_cell: None) -> None:
    from pick_cell import driver, sim

    assert find_driver("vacuum_ejector") is driver.PLUGIN
    assert find_simulator("vacuum_ejector") is sim.PLUGIN
    assert find_driver("box_feeder") is None and find_simulator("box_feeder") is None


def test_config_check_accepts_its_hubs_toml(pick_cell: None) -> None:
    result = hubctl("config", "check", "--config", str(CONFIG))
    assert result.returncode == 0, result.stdout
    assert "(vacuum_ejector, emulate)" in result.stdout and "(box_feeder, emulate)" in result.stdout


def test_its_model_checks_every_operation_reachable(pick_cell: None) -> None:
    result = hubctl("check", "--model", "pick_cell.model:build_model")
    assert result.returncode == 0 and "0 unreachable" in result.stdout, result.stdout


def test_it_runs_to_completion_in_one_process(pick_cell: None) -> None:
    result = hubctl("up", "--in-process", "--config", str(CONFIG))
    assert result.returncode == 0 and "finished: 10/10 operations" in result.stdout, result.stdout


# --- the simulator's physics ---------------------------------------------------------------------

class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def physics(pick_cell: None, clock: Clock) -> Any:
    from pick_cell.sim import EjectorPhysics

    return EjectorPhysics(evacuation_time=0.2, release_time=1.0, blow_off_time=0.1, clock=clock)


def test_the_vacuum_builds_with_suction_and_holds_above_the_switch_point(physics: Any, clock: Clock) -> None:
    from pick_cell.sim import DI_SUPPLY_OK, DI_VACUUM_OK

    physics.set_valves(suction=True, blow_off=False)
    clock.now += 0.1  # 425 mbar: below the 600 mbar switch point
    assert physics.discrete_inputs()[DI_VACUUM_OK] is False
    clock.now += 0.1  # 850 mbar
    inputs = physics.discrete_inputs()
    assert inputs[DI_VACUUM_OK] is True and inputs[DI_SUPPLY_OK] is True


@pytest.mark.parametrize(("blow_off", "held_after_a_tenth"), [(False, True), (True, False)])
def test_releasing_with_blow_off_drops_the_vacuum_faster_and_the_pulse_ends_by_itself(
        physics: Any, clock: Clock, blow_off: bool, held_after_a_tenth: bool) -> None:
    from pick_cell.sim import COIL_BLOW_OFF, DI_VACUUM_OK

    physics.set_valves(suction=True, blow_off=False)
    clock.now += 0.5
    physics.set_valves(suction=False, blow_off=blow_off)
    assert physics.coils()[COIL_BLOW_OFF] is blow_off
    clock.now += 0.1  # 850 mbar less 85 a tenth without blow-off (still above 550), five times that with it
    assert physics.discrete_inputs()[DI_VACUUM_OK] is held_after_a_tenth
    clock.now += 0.1
    assert physics.coils()[COIL_BLOW_OFF] is False


def test_without_supply_pressure_no_vacuum_builds(physics: Any, clock: Clock) -> None:
    from pick_cell.sim import DI_SUPPLY_OK, DI_VACUUM_OK

    physics.supply = False
    physics.set_valves(suction=True, blow_off=False)
    clock.now += 1.0
    assert physics.discrete_inputs()[DI_VACUUM_OK] is False and physics.discrete_inputs()[DI_SUPPLY_OK] is False


# --- the driver against the simulator over Modbus TCP ---------------------------------------------

async def _until(predicate: Callable[[], Awaitable[bool]], what: str) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not await predicate():
        assert time.monotonic() < deadline, f"not within {DEADLINE_S} s: {what}"
        await asyncio.sleep(0.02)


def _driver(port: int) -> Any:
    from pick_cell.driver import PLUGIN

    params = msgspec.convert({"host": "127.0.0.1", "port": port, "timeout": 0.5}, PLUGIN.params)
    return PLUGIN.build("vac", params)


async def test_the_driver_sucks_holds_and_releases_the_simulated_ejector(pick_cell: None) -> None:
    from pick_cell.sim import COIL_BLOW_OFF, EjectorServer

    async with EjectorServer() as server:
        driver = _driver(server.port)
        await driver.connect()
        try:
            await _until(lambda: _connected(driver), "the driver connects")
            assert await driver.read() == {"vacuum_m": False}
            await driver.write({"suction_c": True})
            await _until(lambda: _reads(driver, True), "vacuum_m true after suction on")
            await driver.write({"suction_c": False})
            assert server.physics.coils()[COIL_BLOW_OFF] is True  # releasing blows the box off
            await _until(lambda: _reads(driver, False), "vacuum_m false after release")
            server.physics.blow_off_until = 0.0
            await driver.write({"suction_c": False})  # the controller repeats its command
            assert server.physics.coils()[COIL_BLOW_OFF] is False  # no second blow-off
            assert await driver.enter_safe_state() == {}  # a held box is never dropped
        finally:
            await driver.close()


async def _connected(driver: Any) -> bool:
    return bool(driver.connected)


async def _reads(driver: Any, vacuum: bool) -> bool:
    return (await driver.read())["vacuum_m"] is vacuum


async def test_the_self_test_names_missing_supply_pressure_and_an_absent_gateway(pick_cell: None) -> None:
    from pick_cell.sim import EjectorServer

    async with EjectorServer() as server:
        driver = _driver(server.port)
        await driver.connect()
        try:
            report = await driver.selftest()
            assert report.ok, report
            server.physics.supply = False
            report = await driver.selftest()
            failed = [c for c in report.checks if not c.ok]
            assert [c.name for c in failed] == ["inputs read"] and "compressed air" in failed[0].detail
        finally:
            await driver.close()
        port = server.port
    driver = _driver(port)
    await driver.connect()
    try:
        report = await driver.selftest()
        assert [(c.name, c.ok) for c in report.checks] == [("device answers", False)]
        with pytest.raises(DeviceUnavailable):
            await driver.read()
    finally:
        await driver.close()


# --- the model holds for the driver and the simulator: the model-based test of the ejector's hub -----

@pytest.fixture
def ejector_simulator(pick_cell: None, tmp_path: Path) -> Iterator[str]:
    """`python -m pick_cell.sim --port 0` as a process; its address."""
    log = tmp_path / "ejector-sim.log"
    with log.open("wb") as out:
        process = subprocess.Popen([sys.executable, "-m", "pick_cell.sim", "--port", "0"], stdout=out,
                                   stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.monotonic() + 30.0
        while "listening on" not in log.read_text():
            assert process.poll() is None and time.monotonic() < deadline, f"the simulator did not serve: " \
                                                                           f"{log.read_text()}"
            time.sleep(0.05)
        yield log.read_text().split("listening on", 1)[1].split()[0]
    finally:
        process.terminate()
        process.wait(timeout=10)


@pytest.mark.slow
def test_the_ejector_hub_follows_the_model_with_its_driver_against_its_simulator(
        ejector_simulator: str, tmp_path: Path, station_hub: StationHubs, model_test: ModelTest) -> None:
    host, port = host_port(ejector_simulator)
    text = CONFIG.read_text()
    device = '[hubs.robot.devices.vac]\ntype = "vacuum_ejector"\nmode = "emulate"\nhost = "192.168.1.60"'
    assert device in text
    config = tmp_path / "hubs.toml"
    config.write_text(text.replace(device, f'[hubs.robot.devices.vac]\ntype = "vacuum_ejector"\nmode = "sim"\n'
                                           f'host = "{host}"').replace("port = 502", f"port = {port}"))
    with station_hub(config, "vac") as hub:
        report = model_test(hub.target, "vac", Options(examples=10, max_steps=5))
    print(f"model-based test of vac against its simulator: {report.examples} examples, {report.seconds:.1f} s")


# --- running it: hubctl up, separate processes over Zenoh ------------------------------------------

def _up(config: Path, *args: str, operations: int, tmp_path: Path) -> str:
    began = time.monotonic()
    # A cwd of its own: `up` keeps its logs and the controller's database under ./var/
    result = hubctl("up", "--config", str(config), "--speed", "2", "--time-limit", "120", *args, cwd=tmp_path)
    print(f"hubctl up --config {config.relative_to(ROOT)} {' '.join(args)}: {time.monotonic() - began:.1f} s")
    assert result.returncode == 0, result.stdout
    assert f"finished: {operations}/{operations} operations" in result.stdout, result.stdout
    return result.stdout


@pytest.mark.slow
def test_the_package_runs_to_completion_emulated(pick_cell: None, tmp_path: Path) -> None:
    _up(CONFIG, operations=10, tmp_path=tmp_path)


@pytest.mark.slow
def test_the_package_runs_to_completion_with_its_ejector_against_its_simulator(pick_cell: None,
                                                                             tmp_path: Path) -> None:
    out = _up(CONFIG, "--mode", "sim", operations=10, tmp_path=tmp_path)
    assert "vacuum ejector on a Modbus TCP gateway" in out, out  # the package's simulator served the ejector
    assert "feeder (box_feeder)" in out, out  # no simulator for the feeder: emulated


@pytest.mark.slow
def test_a_station_of_device_types_all_unknown_to_statehub_runs_to_completion(tmp_path: Path) -> None:
    _up(ROOT / "tests" / "custom_station" / "hubs.toml", operations=3, tmp_path=tmp_path)
