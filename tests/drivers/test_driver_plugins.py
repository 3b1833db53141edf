"""Drivers and simulators as plugins: found through real entry points, checked with file, line and key.

A throw-away distribution (a `*.dist-info` with `entry_points.txt`, and its module) is put on
`sys.path`, as `pip install` would: it provides a `gripper` device type with a driver and a
simulator, and a `feeder` type with a driver only.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.config.hubs_toml import ConfigError, load_config
from common.config.modes import DeviceMode
from deploy.local.simworld import SimWorld
from hubs.drivers.registry import ENTRY_POINT_GROUP, driver_types, find_driver
from hubs.factory import check_devices, effective_mode, make_driver
from hubs.plugins import PluginError
from hubs.sim.registry import find_simulator, simulator_types

PLUGIN_MODULE = '''
from __future__ import annotations

import sys

import msgspec

from common.model import Model, Resource, command, measured
from hubs.drivers.base import Driver, SelftestReport
from hubs.drivers.params import DriverParams
from hubs.drivers.registry import DriverPlugin
from hubs.sim.registry import SimServer, SimulatorPlugin, tcp_params


class GripperParams(DriverParams, frozen=True, kw_only=True):
    host: str
    port: int = 4840
    grip_force: float = 20.0


class Gripper(Driver):
    def __init__(self, resource: str, params: GripperParams) -> None:
        self.resource, self.params = resource, params

    async def connect(self) -> None: ...
    async def close(self) -> None: ...

    @property
    def connected(self) -> bool:
        return False

    async def read(self):
        return {}

    async def write(self, commands) -> None: ...

    async def enter_safe_state(self):
        return {"grip_c": False}

    async def selftest(self) -> SelftestReport:
        return SelftestReport(self.resource)


DRIVER = DriverPlugin(GripperParams, Gripper)
FEEDER = DriverPlugin(GripperParams, Gripper)
SERVES = "print('listening on 127.0.0.1:4999', flush=True); import time; time.sleep(60)"
SIMULATOR = SimulatorPlugin("gripper simulator", server=lambda device: SimServer(
    [sys.executable, "-c", SERVES], driver_params=lambda address: {**tcp_params(address), "grip_force": 1.0}))
NOT_A_PLUGIN = "a string"


def build_model() -> Model:
    return Model("cell", (
        Resource("grip", (command("grip.grip_c"), measured("grip.held_m")), device_type="gripper"),
        Resource("feed", (command("feed.run_c"), measured("feed.full_m")), device_type="feeder"),
    ))
'''

ENTRY_POINTS = '''
[statehub.drivers]
gripper = cellplugin:DRIVER
feeder = cellplugin:FEEDER
broken = cellplugin:NOT_A_PLUGIN

[statehub.simulators]
gripper = cellplugin:SIMULATOR
'''

HUBS_TOML = '''
[station]
name = "cell"
model = "cellplugin:build_model"

[controller]
host = "localhost"

[hubs.cell]
host = "localhost"

[hubs.cell.devices.grip]
type = "gripper"
mode = "{mode}"
host = "192.168.0.7"

[hubs.cell.devices.feed]
type = "feeder"
mode = "emulate"
'''


@pytest.fixture
def installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The distribution `cellplugin` installed into a directory on sys.path."""
    site = tmp_path / "site"
    info = site / "cellplugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: cellplugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    (site / "cellplugin.py").write_text(PLUGIN_MODULE)
    monkeypatch.syspath_prepend(str(site))
    yield site
    sys.modules.pop("cellplugin", None)


def station(tmp_path: Path, mode: str, extra: str = "") -> Path:
    path = tmp_path / "hubs.toml"
    path.write_text(HUBS_TOML.format(mode=mode).replace('host = "192.168.0.7"\n', f'host = "192.168.0.7"\n{extra}'))
    return path


def test_an_installed_plugin_is_found_and_builds_its_driver(installed: Path) -> None:
    plugin = find_driver("gripper")
    assert plugin is not None and plugin.params.__name__ == "GripperParams"
    assert {"gripper", "feeder", "nutrunner", "ur"} <= set(driver_types())
    driver = make_driver("grip", "gripper", "real", {"host": "10.0.0.2", "grip_force": 5})
    assert type(driver).__name__ == "Gripper" and driver.resource == "grip"
    assert driver.params.host == "10.0.0.2" and driver.params.grip_force == 5.0  # type: ignore[attr-defined]  # the plugin's own Params
    assert "gripper" in simulator_types() and find_simulator("feeder") is None


def test_without_the_package_there_is_no_driver(tmp_path: Path) -> None:
    assert find_driver("gripper") is None and "gripper" not in driver_types()


def test_a_broken_plugin_names_its_entry_point_and_group(installed: Path) -> None:
    with pytest.raises(PluginError, match=r"entry point broken = cellplugin:NOT_A_PLUGIN \(group 'statehub.drivers'\) "
                                          r"is a str, not a DriverPlugin"):
        find_driver("broken")


def test_sim_mode_runs_a_plugin_type_with_a_simulator_and_emulates_one_without(installed: Path) -> None:
    assert effective_mode("gripper", DeviceMode.REAL, DeviceMode.SIM) is DeviceMode.SIM
    assert effective_mode("feeder", DeviceMode.REAL, DeviceMode.SIM) is DeviceMode.EMULATE
    assert effective_mode("feeder", DeviceMode.REAL, DeviceMode.REAL) is DeviceMode.REAL


def test_an_unknown_parameter_names_file_line_resource_and_key(installed: Path, tmp_path: Path) -> None:
    path = station(tmp_path, "real", 'grip_forse = 3.0\n')
    with pytest.raises(ConfigError) as caught:
        check_devices(load_config(path))
    line = path.read_text().splitlines().index("grip_forse = 3.0") + 1
    problem = caught.value.problems[0]
    assert (problem.file, problem.line, problem.key) == (str(path), line, "hubs.cell.devices.grip.grip_forse")
    assert str(caught.value).startswith(f"{path}:{line}: hubs.cell.devices.grip.grip_forse: unknown parameter "
                                        f"(this driver's parameters: grip_force, host, port, reconnect_factor")


def test_a_mistyped_parameter_names_its_line(installed: Path, tmp_path: Path) -> None:
    path = station(tmp_path, "real", 'port = "opc"\n')
    with pytest.raises(ConfigError) as caught:
        check_devices(load_config(path))
    line = path.read_text().splitlines().index('port = "opc"') + 1
    assert str(caught.value) == (f"{path}:{line}: hubs.cell.devices.grip.port: Expected `int`, got `str` "
                                 f"(found 'opc') [gripper driver, real mode]")


def test_a_real_device_without_driver_names_the_type_and_the_group(tmp_path: Path) -> None:
    path = station(tmp_path, "real")  # the plugin is not installed here
    with pytest.raises(ConfigError) as caught:
        check_devices(load_config(path))
    line = path.read_text().splitlines().index('type = "gripper"') + 1
    problem = caught.value.problems[0]
    assert (problem.line, problem.key) == (line, "hubs.cell.devices.grip.type")
    assert "no driver for device type 'gripper'" in problem.message
    assert f"entry-point group {ENTRY_POINT_GROUP!r}" in problem.message
    check_devices(load_config(station(tmp_path, "emulate")))  # emulated from the model: no driver needed


async def test_the_sim_world_starts_a_plugin_simulator_without_knowing_its_type(installed: Path,
                                                                                tmp_path: Path) -> None:
    config = load_config(station(tmp_path, "emulate"))
    model = config.load_model()
    async with SimWorld(config, model, tmp_path / "sim", say=lambda _line: None) as world:
        assert world.emulated == ["feed (feeder)"]
        assert world.processes["gripper-grip"].address == "127.0.0.1:4999"
        params = json.loads(world.params_files["cell"].read_text())
        assert params == {"grip": {"host": "127.0.0.1", "port": 4999, "grip_force": 1.0}}
        driver = make_driver("grip", "gripper", "sim", {"host": "192.168.0.7", **params["grip"]})
        assert driver.params.host == "127.0.0.1"  # type: ignore[attr-defined]  # the plugin's own Params
    assert not world.processes["gripper-grip"].running



def test_config_check_reports_a_bad_parameter(installed: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    from deploy.cli import main

    path = station(tmp_path, "real", "grip_force = true\n")
    assert main(["config", "check", "--config", str(path)]) == 1
    line = path.read_text().splitlines().index("grip_force = true") + 1
    assert f"{path}:{line}: hubs.cell.devices.grip.grip_force: Expected `float`, got `bool`" in capsys.readouterr().err
    assert main(["config", "check", "--config", str(station(tmp_path, "real"))]) == 0
