"""`hubctl new-station` and `hubctl new-device` (deploy/scaffold, issue 11 item 3).

* new-station writes a project that is valid as it is: its hubs.toml fits its model, the
  model runs to completion; names and directories it must not use are refused.
* new-device takes the model's resources of the type, or adds a stub resource (and says
  so); writes the driver skeleton with the variable contract, the entry point, the
  hubs.toml entry and the model-based test; refuses what it cannot do safely.
* End to end (slow): a generated project installed into the venv passes its own tests
  with the device emulated, and fails them once the device is "real" and its driver not
  written, with a message naming the driver and the unwritten variables.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from common.config.hubs_toml import load_station
from common.model import Model, Resource
from deploy.cli import main as hubctl
from deploy.scaffold.device import check_same_contract
from deploy.scaffold.files import ScaffoldError
from tests.scaffold_support import generated_projects_removed, install, venv_lock

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def project(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A fresh `hubctl new-station` project, importable in this process (not installed)."""
    name = "scaffold_cell"
    root = tmp_path / name
    with venv_lock():  # new-station refuses the name while another test has it installed
        assert hubctl(["new-station", name, "--dir", str(root)]) == 0
    monkeypatch.syspath_prepend(str(root))
    yield root
    for module in [m for m in sys.modules if m == name or m.startswith(f"{name}.")]:
        del sys.modules[module]


def fresh_station(root: Path) -> tuple[object, Model]:
    for module in [m for m in sys.modules if m.startswith("scaffold_cell")]:
        del sys.modules[module]
    importlib.invalidate_caches()
    return load_station(root / "hubs.toml")


# --- new-station ---------------------------------------------------------------------------------

def test_new_station_writes_a_project_that_runs_as_it_is(project: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted(str(p.relative_to(project)) for p in project.rglob("*") if p.is_file())
    assert files == ["hubs.toml", "pyproject.toml", "scaffold_cell/__init__.py", "scaffold_cell/devices/__init__.py",
                     "scaffold_cell/drivers/__init__.py", "scaffold_cell/model.py", "tests/conftest.py",
                     "tests/test_station.py"]
    pyproject = tomllib.loads((project / "pyproject.toml").read_text())
    assert pyproject["project"]["name"] == "scaffold_cell" and pyproject["project"]["dependencies"] == ["statehub"]
    _, model = fresh_station(project)
    assert model.problems() == [] and [r.device_type for r in model.resources] == ["clamp"]
    capsys.readouterr()
    assert hubctl(["up", "--in-process", "--config", str(project / "hubs.toml")]) == 0
    assert "finished: 2/2 operations" in capsys.readouterr().out


@pytest.mark.parametrize(("name", "reason"), [
    ("Bad-Name", "must be a lowercase Python identifier"),
    ("class", "must be a lowercase Python identifier"),
    ("json", "a Python module named 'json' is importable already"),
])
def test_new_station_refuses_a_name_that_is_no_package_of_its_own(name: str, reason: str, tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["new-station", name, "--dir", str(tmp_path / "p")]) == 2
    assert reason in capsys.readouterr().err and not (tmp_path / "p").exists()


def test_new_station_never_writes_into_a_directory_in_use(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    assert hubctl(["new-station", "other_cell", "--dir", str(tmp_path)]) == 2
    assert "is not an empty directory" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


# --- new-device ----------------------------------------------------------------------------------

def test_new_device_writes_the_driver_skeleton_of_the_models_resources(project: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["new-device", "clamp", "--station", str(project)]) == 0
    out = capsys.readouterr().out
    assert "device type clamp: resource clamp of model scaffold_cell" in out
    driver = (project / "scaffold_cell" / "drivers" / "clamp.py").read_text()
    # the variable contract, from the model, with the domains and descriptions
    assert '"closed_m": (False, True),  # the clamp is closed (its end-position sensor)' in driver
    assert '"close_c": (False, True),  # close the clamp' in driver
    assert "class ClampDriver(Driver):" in driver
    assert "PLUGIN = DriverPlugin(params=Params, build=ClampDriver)" in driver
    pyproject = tomllib.loads((project / "pyproject.toml").read_text())
    assert pyproject["project"]["entry-points"]["statehub.drivers"] == {"clamp": "scaffold_cell.drivers.clamp:PLUGIN"}
    config, _ = fresh_station(project)
    device = config.device("clamp")  # type: ignore[attr-defined]  # the generated project's config
    assert (device.mode, device.params) == ("emulate", {"host": "192.0.2.10", "port": 502})
    test = (project / "tests" / "test_clamp.py").read_text()
    assert '@pytest.mark.parametrize("resource", ["clamp"])' in test and "model_test(hub.target, resource" in test


def test_new_device_keeps_what_exists_unless_forced(project: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["new-device", "clamp", "--station", str(project)]) == 0
    driver = project / "scaffold_cell" / "drivers" / "clamp.py"
    driver.write_text("# written by hand\n")
    assert hubctl(["new-device", "clamp", "--station", str(project)]) == 2
    assert "clamp.py exists already: not overwritten" in capsys.readouterr().err
    assert driver.read_text() == "# written by hand\n"
    assert hubctl(["new-device", "clamp", "--station", str(project), "--force"]) == 0
    assert "entry point clamp = 'scaffold_cell.drivers.clamp:PLUGIN' is there already" in capsys.readouterr().out
    assert "class ClampDriver" in driver.read_text()
    assert (project / "pyproject.toml").read_text().count("scaffold_cell.drivers.clamp:PLUGIN") == 1
    assert (project / "hubs.toml").read_text().count('host = "192.0.2.10"') == 1


def test_new_device_of_a_type_the_model_lacks_adds_a_stub_resource(project: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["new-device", "label_printer", "--station", str(project)]) == 0
    out = capsys.readouterr().out
    assert ("device type label_printer: model scaffold_cell has no resource of it; added a stub resource model and "
            "a resource 'label_printer'") in out
    assert (project / "scaffold_cell" / "devices" / "label_printer.py").is_file()
    config, model = fresh_station(project)  # hubs.toml fits the model: the new hub serves the new resource
    assert model.problems() == [] and model.resource_by_name["label_printer"].device_type == "label_printer"
    assert config.hub_of("label_printer").name == "label_printer"  # type: ignore[attr-defined]  # the generated project's config
    assert '"on_m": (False, True),' in (project / "scaffold_cell" / "drivers" / "label_printer.py").read_text()


def test_new_device_without_the_models_markers_changes_nothing(project: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    model = project / "scaffold_cell" / "model.py"
    model.write_text("\n".join(line for line in model.read_text().splitlines() if "hubctl new-device" not in line))
    before = {p: p.read_text() for p in project.rglob("*") if p.is_file()}
    assert hubctl(["new-device", "label_printer", "--station", str(project)]) == 2
    assert "has no line '# hubctl new-device adds the imports" in capsys.readouterr().err
    assert {p: p.read_text() for p in project.rglob("*") if p.is_file()} == before


def test_new_device_never_replaces_an_entry_point_that_names_another_driver(
        project: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pyproject = project / "pyproject.toml"
    pyproject.write_text(pyproject.read_text().replace('[project.entry-points."statehub.drivers"]\n',
                                                       '[project.entry-points."statehub.drivers"]\n'
                                                       'clamp = "vendor_clamps.driver:PLUGIN"\n'))
    before = {p: p.read_text() for p in project.rglob("*") if p.is_file()}
    assert hubctl(["new-device", "clamp", "--station", str(project)]) == 2
    assert ("entry point clamp of group statehub.drivers names 'vendor_clamps.driver:PLUGIN', not "
            "'scaffold_cell.drivers.clamp:PLUGIN': change it by hand") in capsys.readouterr().err
    assert {p: p.read_text() for p in project.rglob("*") if p.is_file()} == before


def test_new_device_needs_a_station_project(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["new-device", "clamp", "--station", str(tmp_path)]) == 2
    assert "is not a station project (no hubs.toml and pyproject.toml there)" in capsys.readouterr().err


def test_one_driver_serves_only_resources_of_one_contract(project: Path) -> None:
    from scaffold_cell.model import clamp  # type: ignore[import-not-found]  # the project the fixture generated

    other = clamp("other")
    narrower = Resource("narrow", other.variables[:1], device_type="clamp")
    check_same_contract("clamp", [clamp("a"), other])
    with pytest.raises(ScaffoldError, match="'a' and 'narrow' are both of device type 'clamp' but differ"):
        check_same_contract("clamp", [clamp("a"), narrower])


async def test_the_skeleton_names_itself_and_the_variables_still_to_write(project: Path) -> None:
    assert hubctl(["new-device", "clamp", "--station", str(project)]) == 0
    fresh_station(project)
    from scaffold_cell.drivers.clamp import PLUGIN  # type: ignore[import-not-found]  # generated by the test

    driver = PLUGIN.build("clamp", msgspec.convert({"host": "192.0.2.10"}, PLUGIN.params))
    with pytest.raises(NotImplementedError, match=r"driver ClampDriver \(scaffold_cell.drivers.clamp\) of resource "
                                                  r"'clamp': read\(\) returns no value for closed_m \(False, True\)"):
        await driver.read()
    with pytest.raises(NotImplementedError, match=r"write\(\) does not apply close_c \(False, True\)"):
        await driver.write({"close_c": True})
    with pytest.raises(msgspec.ValidationError, match="hots"):
        msgspec.convert({"host": "x", "hots": "y"}, PLUGIN.params)  # typed: a misspelt parameter is an error


# --- end to end: the generated tests, installed ----------------------------------------------------

def generated_tests(project: Path) -> subprocess.CompletedProcess[str]:
    began = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=project, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=600, check=False)
    print(f"generated tests ({project.name}): exit {result.returncode}, {time.monotonic() - began:.1f} s")
    return result


@pytest.mark.slow
def test_a_generated_project_passes_its_tests_until_its_device_is_real_and_fails_naming_the_driver(
        tmp_path: Path) -> None:
    project = tmp_path / "scaffold_cell"
    with generated_projects_removed():
        assert hubctl(["new-station", "scaffold_cell", "--dir", str(project)]) == 0
        assert hubctl(["new-device", "clamp", "--station", str(project)]) == 0
        install(project)
        passing = generated_tests(project)
        assert passing.returncode == 0 and "4 passed" in passing.stdout, passing.stdout
        config = project / "hubs.toml"
        config.write_text(config.read_text().replace('mode = "emulate"', 'mode = "real"', 1))
        failing = generated_tests(project)
    assert failing.returncode == 1, failing.stdout
    assert "1 failed, 3 passed" in failing.stdout, failing.stdout
    assert ("NotImplementedError: driver ClampDriver (scaffold_cell.drivers.clamp) of resource 'clamp': read() "
            "returns no value for closed_m (False, True)") in failing.stdout, failing.stdout
