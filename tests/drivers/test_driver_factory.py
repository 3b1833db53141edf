"""make_driver: modes, device types and parameter errors."""

from __future__ import annotations

import pytest

from hubs.drivers.camera_tracker import CameraTracker
from hubs.drivers.dock_modbus import DockModbus
from hubs.drivers.mir_rest import MirRest
from hubs.drivers.registry import driver_types
from hubs.drivers.rsp_modbus import RspModbus
from hubs.drivers.ur_rtde import UrRtde
from hubs.factory import make_driver


def test_known_types() -> None:
    assert {"camera", "dock", "lift", "mir", "nutrunner", "rfid", "rsp", "ur"} <= set(driver_types())


def test_emulate_is_built_elsewhere() -> None:
    with pytest.raises(ValueError, match="emulate"):
        make_driver("nr", "nutrunner", "emulate", {})


def test_unknown_mode_and_type() -> None:
    with pytest.raises(ValueError, match="unknown mode 'fake'"):
        make_driver("nr", "nutrunner", "fake", {})
    with pytest.raises(ValueError, match="no driver for device type 'toaster'"):
        make_driver("t", "toaster", "sim", {})


def test_missing_parameters_are_named() -> None:
    with pytest.raises(ValueError, match=r"'mir' \(mir, real\).*'host'"):
        make_driver("mir", "mir", "real", {})
    with pytest.raises(ValueError, match="'serial_port'"):
        make_driver("rfid", "rfid", "sim", {})
    with pytest.raises(ValueError, match="'poses'"):
        make_driver("ur", "ur", "real", {"host": "192.168.1.10"})
    with pytest.raises(ValueError, match="pin must be"):
        make_driver("nr", "nutrunner", "real", {"run_pin": "C9"})
    with pytest.raises(ValueError, match="unknown zone"):
        make_driver("cam", "camera", "real", {"host": "10.0.0.5", "zones": {"kitchen": [[0, 0, 1, 1]]}})


def test_sim_mode_fills_in_the_simulator_addresses() -> None:
    rsp = make_driver("rsp", "rsp", "sim", {})
    assert isinstance(rsp, RspModbus) and rsp.link.where == "127.0.0.1:5020 unit 1"
    dock = make_driver("dock", "dock", "sim", {"port": 1502})
    assert isinstance(dock, DockModbus) and dock.link.port == 1502 and dock.di_base == 8
    mir = make_driver("mir", "mir", "sim", {})
    assert isinstance(mir, MirRest) and mir.base_url == "http://127.0.0.1:8080/api/v2.0.0"
    cam = make_driver("cam", "camera", "sim", {})
    assert isinstance(cam, CameraTracker) and cam.port == 7001 and set(cam.zones) == {"robot", "shared"}
    ur = make_driver("ur", "ur", "sim", {"poses": {"home": {"q": [0, 0, 0, 0, 0, 0]}}})
    assert isinstance(ur, UrRtde) and ur.host == "127.0.0.2" and ur.config.backend == "sim"
    real = make_driver("ur", "ur", "real", {"host": "192.168.1.10", "poses": {"home": {"q": [0, 0, 0, 0, 0, 0]}}})
    assert isinstance(real, UrRtde) and real.config.backend == "real"
