"""The deployment file: the repository's hubs.toml loads; each mistake is reported with file, line and key."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config.hostnames import host_problem
from common.config.hubs_toml import ConfigError, KeyLines, StationConfig, check_against_model, load_config, parse_config
from common.config.modes import DeviceMode, NetworkMode, SecurityMode
from common.model import Model, Resource, command, measured

REPO_FILE = Path(__file__).resolve().parent.parent / "hubs.toml"

GOOD = """\
[station]
name = "demo"
model = "tests.test_config:tiny_model"

[network]
mode = "peer"
connect = ["tcp/127.0.0.1:7447"]
lease_ms = 2000

[controller]
host = "decs"
listen = ["tcp/127.0.0.1:7447"]

[hubs.pi-tool]
host = "pi-tool"
rate_hz = 50

[hubs.pi-tool.devices.nr]
type = "nutrunner"
mode = "emulate"
bus = 1

[hubs.rfidcam]
host = "rfidcam"

[hubs.rfidcam.devices.rfid]
type = "rfid"
mode = "sim"
"""


def tiny_model() -> Model:
    return Model("demo", (
        Resource("nr", (command("nr.run_c"), measured("nr.run_m")), device_type="nutrunner"),
        Resource("rfid", (measured("rfid.verified_m"),), device_type="rfid"),
    ))


def error_of(text: str, **kwargs: object) -> ConfigError:
    with pytest.raises(ConfigError) as caught:
        parse_config(text, "station.toml", **kwargs)  # type: ignore[arg-type]  # each test passes its keywords
    return caught.value


def line_of(text: str, needle: str, occurrence: int = 1) -> int:
    """The 1-based line of the `occurrence`-th line containing `needle`."""
    found = [i for i, line in enumerate(text.splitlines(), start=1) if needle in line]
    return found[occurrence - 1]


# --- the repository's file --------------------------------------------------------------------

def test_the_repository_hubs_toml_loads() -> None:
    config = load_config(REPO_FILE)
    assert config.station.name == "engine_assembly"
    assert set(config.hubs) == {"pi-tool", "pi-rsp", "pi-dock", "mircom", "ur10", "rfidcam", "agv", "human"}
    assert {r: h.name for r, h in config.resources.items()} == {
        "nr": "pi-tool", "lift": "pi-tool", "rsp": "pi-rsp", "dock": "pi-dock", "mir": "mircom", "ur": "ur10",
        "rfid": "rfidcam", "cam": "rfidcam", "agv": "agv", "human": "human"}
    assert config.controller.host == "decs"
    assert config.network_for("controller").listen == ["tcp/0.0.0.0:7447"]
    assert config.network_for("pi-tool").connect == config.network.connect
    assert config.device("nr").params == {"bus": 1, "address": 0x20}
    local = config.loopback_network("human", port=17447)
    assert (local.mode, local.listen, local.connect) == ("peer", ["tcp/127.0.0.1:0"], ["tcp/127.0.0.1:17447"])
    assert config.loopback_network("controller", port=17447).listen == ["tcp/127.0.0.1:17447"]


def test_the_repository_hubs_toml_matches_its_station_model() -> None:
    pytest.importorskip("common.stations.engine_assembly")
    config = load_config(REPO_FILE)
    check_against_model(config, config.load_model())


def test_a_good_file() -> None:
    config = parse_config(GOOD, model=tiny_model())
    assert isinstance(config, StationConfig)
    hub = config.hubs["pi-tool"]
    assert (hub.host, hub.rate_hz, hub.command_timeout_s, hub.ssh_user) == ("pi-tool", 50.0, 1.0, "pi")
    assert config.device("rfid").mode is DeviceMode.SIM and config.device("nr").mode is DeviceMode.EMULATE
    assert config.network.mode is NetworkMode.PEER and config.security.mode is SecurityMode.INSECURE
    assert config.device("nr").line == line_of(GOOD, "[hubs.pi-tool.devices.nr]")
    assert config.controller.command_rate_hz == 10.0
    net = config.network_for("pi-tool")
    assert (net.mode, net.listen, net.connect, net.lease_ms) == ("peer", [], ["tcp/127.0.0.1:7447"], 2000)


def test_model_is_imported_from_the_station_section(tmp_path: Path) -> None:
    path = tmp_path / "hubs.toml"
    path.write_text(GOOD)
    assert load_config(path).load_model().name == "demo"
    path.write_text(GOOD.replace("tests.test_config:tiny_model", "tests.test_config:nothing_here"))
    with pytest.raises(ConfigError) as caught:
        load_config(path).load_model()
    assert str(caught.value).startswith(f"{path}:3: station.model: module 'tests.test_config' has no attribute")


# --- each mistake names file, line and key ----------------------------------------------------------

CASES = [
    # (description, replace this, by this, key, needle for the line, message fragment)
    ("unknown section", "[network]", "[netwrok]", "netwrok", "[netwrok]", "unknown section"),
    ("unknown key", 'host = "decs"', 'host = "decs"\nhsot = "x"', "controller.hsot", "hsot",
     "unknown key (known keys: command_rate_hz"),
    ("unknown hub key", "rate_hz = 50", "rate_hz = 50\nrate = 3", "hubs.pi-tool.rate", "rate = 3", "unknown key"),
    ("wrong type", "rate_hz = 50", 'rate_hz = "fast"', "hubs.pi-tool.rate_hz", "rate_hz",
     "Expected `float`, got `str` (found a string 'fast')"),
    ("out of range", "rate_hz = 50", "rate_hz = 0", "hubs.pi-tool.rate_hz", "rate_hz", "Expected `float` > 0"),
    ("lease too short", "lease_ms = 2000", "lease_ms = 20", "network.lease_ms", "lease_ms", ">= 100"),
    ("unknown device mode", 'mode = "sim"', 'mode = "simulate"', "hubs.rfidcam.devices.rfid.mode",
     'mode = "simulate"', "unknown mode 'simulate' (expected one of: emulate, sim, real)"),
    ("unknown network mode", 'mode = "peer"', 'mode = "router"', "network.mode", 'mode = "router"',
     "unknown mode 'router' (expected one of: peer, client)"),
    ("unknown execution", 'host = "decs"\n', 'host = "decs"\nexecution = "parallel"\n', "controller.execution",
     'execution = "parallel"', "unknown execution 'parallel' (expected one of: partial_order, trace, sequence)"),
    ("duplicate hub", "[hubs.rfidcam]\n", "[hubs.pi-tool]\n", "hubs.pi-tool", "[hubs.pi-tool]",
     "duplicate hub name 'pi-tool'"),
    ("resource in two hubs", "[hubs.rfidcam.devices.rfid]", "[hubs.rfidcam.devices.nr]",
     "hubs.rfidcam.devices.nr", "[hubs.rfidcam.devices.nr]", "already served by hub 'pi-tool'"),
    ("missing key", 'host = "rfidcam"', 'ssh_user = "pi"', "hubs.rfidcam", "[hubs.rfidcam]", "missing key 'host'"),
    ("device not a table", "[hubs.rfidcam.devices.rfid]\ntype = \"rfid\"\nmode = \"sim\"\n",
     "devices.rfid = 3\n", "hubs.rfidcam.devices.rfid", "devices.rfid = 3", "must be a table, not an integer"),
    ("bad hub name", "[hubs.rfidcam]\n", '[hubs."rfid/cam"]\nhost = "x"\n[hubs.rfidcam]\n', "hubs.rfid/cam",
     "rfid/cam", "cannot be a key chunk"),
    ("client listens", 'mode = "peer"', 'mode = "client"\nlisten = ["tcp/0.0.0.0:7447"]', "network.listen",
     'listen = ["tcp/0.0.0.0:7447"]', "a zenoh client cannot listen"),
    ("bad model spec", 'model = "tests.test_config:tiny_model"', 'model = "tests.test_config"', "station.model",
     "model =", "must be 'module:attribute'"),
    ("invalid TOML", "rate_hz = 50", "rate_hz = ", "", "rate_hz", "invalid TOML: Invalid value"),
    ("ssh option as user", 'host = "pi-tool"', 'host = "pi-tool"\nssh_user = "-oProxyCommand=touch /tmp/x"',
     "hubs.pi-tool.ssh_user", "ssh_user =", "not starting with '-'"),
    ("user with a space", 'host = "pi-tool"', 'host = "pi-tool"\nssh_user = "pi x"', "hubs.pi-tool.ssh_user",
     "ssh_user =", "is not a user name"),
    ("option as host", 'host = "pi-tool"', 'host = "-oProxyCommand=x"', "hubs.pi-tool.host", 'host = "-o',
     "neither a hostname"),
    ("host with a path", 'host = "rfidcam"', 'host = "rfid/cam"', "hubs.rfidcam.host", 'host = "rfid/cam"',
     "neither a hostname"),
    ("controller host", 'host = "decs"', 'host = "decs pc"', "controller.host", 'host = "decs pc"',
     "neither a hostname"),
]


@pytest.mark.parametrize("host", ["decs", "robot-ecu.local", "192.168.1.50", "::1", "fe80::1", "localhost",
                                  "pi-tool.station.example."])
def test_hostnames_and_addresses_are_accepted(host: str) -> None:
    assert host_problem(host) is None


@pytest.mark.parametrize("host", ["", "-x", "a..b", "a_b", "host:22", "999.1.1.1", "x" * 64])
def test_what_is_no_host_is_refused(host: str) -> None:
    assert host_problem(host) is not None


@pytest.mark.parametrize(("old", "new", "key", "needle", "fragment"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_mistakes_name_file_line_and_key(old: str, new: str, key: str, needle: str, fragment: str) -> None:
    assert old in GOOD
    text = GOOD.replace(old, new, 1)
    error = error_of(text)
    assert len(error.problems) == 1, str(error)
    problem = error.problems[0]
    occurrence = 2 if "duplicate hub" in fragment else 1
    assert (problem.file, problem.line, problem.key) == ("station.toml", line_of(text, needle, occurrence), key)
    assert fragment in problem.message
    prefix = f"station.toml:{problem.line}: {key}: " if key else f"station.toml:{problem.line}: "
    assert str(error).startswith(prefix)


def test_inline_device_tables_point_at_their_line() -> None:
    text = GOOD.replace('[hubs.rfidcam.devices.rfid]\ntype = "rfid"\nmode = "sim"\n',
                        'devices.rfid = { type = "rfid", mode = "emu" }\n')
    error = error_of(text)
    assert error.line == line_of(text, "devices.rfid =") and error.key == "hubs.rfidcam.devices.rfid.mode"


def test_every_problem_is_reported_at_once() -> None:
    text = GOOD.replace("rate_hz = 50", 'rate_hz = "x"\nbogus = 1').replace('mode = "sim"', 'mode = "fake"')
    error = error_of(text)
    assert [p.key for p in error.problems] == ["hubs.pi-tool.rate_hz", "hubs.pi-tool.bogus",
                                               "hubs.rfidcam.devices.rfid.mode"]
    assert str(error).startswith("3 problems:\n  station.toml:")


def test_missing_sections() -> None:
    error = error_of('[hubs.a]\nhost = "x"\n')
    assert [p.key for p in error.problems] == ["station", "controller"]


# --- against the station model ------------------------------------------------------------------------

def test_a_resource_the_model_lacks() -> None:
    text = GOOD.replace("[hubs.rfidcam.devices.rfid]", "[hubs.rfidcam.devices.rfid2]")
    error = error_of(text, model=tiny_model())
    keys = {p.key: p for p in error.problems}
    lacks = keys["hubs.rfidcam.devices.rfid2"]
    assert lacks.line == line_of(text, "devices.rfid2]") and "not in station model 'demo'" in lacks.message
    unserved = keys["station.model"]
    assert unserved.line == line_of(text, "model =") and "resource 'rfid' of station model 'demo'" in unserved.message


def test_a_device_type_differing_from_the_model() -> None:
    text = GOOD.replace('type = "rfid"', 'type = "camera"')
    error = error_of(text, model=tiny_model())
    assert error.key == "hubs.rfidcam.devices.rfid.type" and error.line == line_of(text, 'type = "camera"')
    assert "type 'camera', but resource 'rfid' of the model is a 'rfid'" in str(error)


def test_errors_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "station.toml"
    path.write_text(GOOD.replace('mode = "sim"', 'mode = "fake"'))
    line = line_of(GOOD, 'mode = "sim"')
    with pytest.raises(ConfigError, match=rf"^{path}:{line}: hubs\.rfidcam\.devices\.rfid\.mode: unknown mode"):
        load_config(path)


# --- the line finder --------------------------------------------------------------------------------

def test_key_lines_skip_multiline_values() -> None:
    text = '''\
[network]
listen = [
  "tcp/[::]:7447",   # brackets in strings
  "x = 1",
]
connect = []
doc = """
fake = 1
"""
[hubs."a.b".devices]
real = 1
'''
    lines = KeyLines(text)
    assert lines.line_of(("network", "listen")) == 2
    assert lines.line_of(("network", "connect")) == 6
    assert lines.line_of(("network", "fake")) == 1  # not a key: falls back to its table
    assert lines.line_of(("hubs", "a.b", "devices", "real")) == 11
    assert lines.line_of(("hubs", "a.b")) == 10
    assert lines.line_of(("nowhere",)) is None


@pytest.mark.parametrize("mode", [DeviceMode.REAL, DeviceMode.SIM])
def test_every_device_of_the_repository_hubs_toml_builds_its_driver(mode: DeviceMode) -> None:
    """Switching a device to real (or sim) needs no other edit: its driver's parameters are all there."""
    from common.config.hubs_toml import load_station
    from hubs.drivers.base import Driver
    from hubs.drivers.registry import driver_types
    from hubs.factory import build_drivers, effective_mode

    config, model = load_station(REPO_FILE)
    with_driver = [r for r, d in config.resources.items() if config.device(r).type in driver_types()]
    assert {config.device(r).type for r in with_driver} >= {"nutrunner", "lift", "rsp", "dock", "ur", "mir", "rfid",
                                                             "camera"}
    for hub in config.hubs:
        devices = [r for r in config.hubs[hub].devices if r in with_driver]
        if not devices:
            continue  # the operator and the AGV: emulated only
        drivers = build_drivers(config, hub, model, mode=mode)
        # `--mode sim` leaves a type without a simulator emulated (the operator: its page has none)
        devices = [r for r in devices if effective_mode(config.device(r).type, DeviceMode.EMULATE, mode) == mode]
        assert all(isinstance(drivers[r], Driver) and type(drivers[r]).__name__ != "EmulatedDriver" for r in devices)
