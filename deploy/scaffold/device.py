"""`hubctl new-device TYPE`: a driver skeleton for a device type of a station's model, and its test.

Reads the station's model (hubs.toml names it), takes its resources of device type TYPE,
or, when it has none, writes a stub resource model for TYPE and adds a resource of it to
the model (saying so), then writes:

* NAME/drivers/TYPE.py: the driver skeleton. It lists the variable contract (measured and
  command variables with their domains, from the model), takes a typed `Params` Struct,
  and its `read`/`write` raise NotImplementedError naming the variables still to write;
* tests/test_TYPE.py: the model-based test of each resource of TYPE against its hub
  (deploy/modeltest through the `model_test` fixture), passing while the device is
  emulated and failing, with the driver's message, once it is "real" and not written;
* the entry point `TYPE = "NAME.drivers.TYPE:PLUGIN"` (group statehub.drivers) in
  pyproject.toml, and the device's table in hubs.toml (mode "emulate", the driver's
  parameters), a new hub for resources no hub serves yet.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from common.config.hubs_toml import ConfigError, StationConfig, check_against_model, load_config
from common.model import Model, Resource, Variable

from .files import Changes, ScaffoldError, add_to_table, check_name, insert_at_marker, render, toml_key

DRIVER_GROUP = "statehub.drivers"
IMPORT_MARKER = "hubctl new-device adds the imports of new device models below this line"
RESOURCE_MARKER = "hubctl new-device adds new resources above this line"
PLACEHOLDER_HOST = "192.0.2.10"  # TEST-NET-1: documentation only, never a real device
MAX_LISTED_VALUES = 12


@dataclass
class Station:
    root: Path
    config: StationConfig
    model: Model
    package: str  # the top-level package of the model module
    model_file: Path


@contextlib.contextmanager
def _importable(root: Path, package: str) -> Iterator[None]:
    """Import the project from `root`, afresh (it may be installed, or changed since)."""
    for name in [m for m in sys.modules if m == package or m.startswith(f"{package}.")]:
        del sys.modules[name]
    importlib.invalidate_caches()
    sys.path.insert(0, str(root))
    try:
        yield
    finally:
        sys.path.remove(str(root))


def load_project(root: Path) -> Station:
    config_path = root / "hubs.toml"
    if not config_path.is_file() or not (root / "pyproject.toml").is_file():
        raise ScaffoldError(f"{root} is not a station project (no hubs.toml and pyproject.toml there): give its "
                            f"directory with --station, or make one with `hubctl new-station NAME`")
    config = load_config(config_path)
    module_name, _, attribute = config.station.model.partition(":")
    package = module_name.split(".")[0]
    with _importable(root, package):
        try:
            module = importlib.import_module(module_name)
            target = getattr(module, attribute)
            model = target() if callable(target) else target
        except Exception as exc:
            raise ScaffoldError(f"{config_path}: station.model {config.station.model!r} does not load: "
                                f"{type(exc).__name__}: {exc}") from exc
    model_file = Path(module.__file__ or "").resolve()
    if not isinstance(model, Model):
        raise ScaffoldError(f"{config.station.model} gave a {type(model).__name__}, not a Model")
    if not model_file.is_relative_to(root.resolve()):
        raise ScaffoldError(f"the model {config.station.model} is loaded from {model_file}, outside the project "
                            f"{root}: run this where its source is")
    return Station(root, config, model, package, model_file)


# --- the variable contract ---------------------------------------------------------------------

def _values(variable: Variable) -> str:
    """The domain as Python source, in the quotes ruff's format writes."""
    values = variable.domain.values
    integers = [v for v in values if isinstance(v, int)]
    if len(values) > MAX_LISTED_VALUES and len(integers) == len(values):
        return f"tuple(range({integers[0]}, {integers[-1] + 1}))"
    items = [f'"{v}"' if isinstance(v, str) else repr(v) for v in values]
    return f"({items[0]},)" if len(items) == 1 else f"({', '.join(items)})"


def _contract(variables: tuple[Variable, ...]) -> str:
    return "".join(f'    "{v.name}": {_values(v)},  # {v.description or v.domain.describe()}\n' for v in variables)


def check_same_contract(device_type: str, resources: list[Resource]) -> None:
    """Every resource of a device type has the variables of the first one: one driver serves them all."""
    def signature(resource: Resource) -> dict[str, tuple[str, tuple[object, ...]]]:
        return {v.name: (v.kind.value, v.domain.values) for v in (*resource.measured, *resource.commands)}

    first = resources[0]
    for other in resources[1:]:
        if signature(other) != signature(first):
            raise ScaffoldError(f"resources {first.name!r} and {other.name!r} are both of device type {device_type!r} "
                                f"but differ in their measured or command variables or domains: one driver cannot "
                                f"serve both; give them different device types")


def _examples(resource: Resource) -> dict[str, str]:
    read = "".join(f'\n        #   values["{v.name}"] = ...  # one of {_values(v)}' for v in resource.measured)
    write = "".join(f'\n        #   ... = commands["{v.name}"]  # one of {_values(v)}\n'
                    f'        #   applied["{v.name}"] = commands["{v.name}"]' for v in resource.commands)
    return {"read_example": f", e.g.{read}" if read else " (none)",
            "write_example": f", e.g.{write}" if write else " (none)"}


# --- the command ------------------------------------------------------------------------------

def new_device(device_type: str, root: Path, *, force: bool = False) -> list[str]:
    check_name("device type", device_type)
    station = load_project(root)
    changes = Changes(root.resolve())
    driver = root / station.package / "drivers" / f"{device_type}.py"
    test = root / "tests" / f"test_{device_type}.py"
    # Everything that can refuse is checked before anything is written.
    for path in (driver, test):
        changes.check_new(path, force=force)
    module = f"{station.package}.drivers.{device_type}"
    registered = _entry_point_registered(root / "pyproject.toml", device_type, f"{module}:PLUGIN")
    resources = [r for r in station.model.resources if r.device_type == device_type]
    if resources:
        changes.lines.append(f"device type {device_type}: resource{'s' if len(resources) > 1 else ''} "
                             f"{', '.join(r.name for r in resources)} of model {station.model.name}")
    else:
        station = _add_stub_resource(station, device_type, changes)
        resources = [r for r in station.model.resources if r.device_type == device_type]
    check_same_contract(device_type, resources)
    names = ", ".join(f"resource {r.name}" for r in resources)
    first = resources[0]
    changes.create(driver, render(
        "driver.py", type=device_type, station=station.model.name, resources=names, cls=_class_name(device_type),
        measured=_contract(first.measured), commands=_contract(first.commands), **_examples(first)), force=force)
    testable = [r.name for r in resources if r.commands]
    if testable:
        changes.create(test, render(
            "test_device.py", type=device_type, station=station.model.name, resources=names,
            resource_list=", ".join(f'"{name}"' for name in testable)), force=force)
    else:
        changes.lines.append(f"  no test: {names} {'has' if len(resources) == 1 else 'have'} no command variables "
                             f"(nothing for a model-based test to command)")
    _register_entry_point(root / "pyproject.toml", device_type, f"{module}:PLUGIN", changes, registered)
    _add_to_hubs_toml(station, resources, changes)
    changes.lines += [
        "next:",
        "  python -m pip install --no-build-isolation -e .   # again: statehub finds the driver by its entry point",
        f"  python -m pytest tests/test_{device_type}.py" if testable else "  python -m pytest",
        f"  then write {station.package}/drivers/{device_type}.py and set mode = \"real\" in hubs.toml",
    ]
    return changes.lines


def _class_name(device_type: str) -> str:
    return "".join(part.capitalize() for part in device_type.split("_") if part) + "Driver"


def _add_stub_resource(station: Station, device_type: str, changes: Changes) -> Station:
    if device_type in station.model.resource_by_name:
        other = station.model.resource_by_name[device_type]
        raise ScaffoldError(f"model {station.model.name} has no resource of device type {device_type!r}, and its "
                            f"resource named {device_type!r} is a {other.device_type!r}: cannot add a stub resource "
                            f"of that name")
    stub = station.root / station.package / "devices" / f"{device_type}.py"
    if stub.exists():
        raise ScaffoldError(f"{stub} exists but model {station.model.name} has no resource of device type "
                            f"{device_type!r}: call {device_type}(...) in build_model() ({station.model_file}) first")
    text = station.model_file.read_text(encoding="utf-8")
    text = insert_at_marker(text, IMPORT_MARKER, f"from {station.package}.devices.{device_type} import "
                                                     f"{device_type}", station.model_file)
    text = insert_at_marker(text, RESOURCE_MARKER, f'{device_type}("{device_type}"),', station.model_file)
    changes.lines.append(f"device type {device_type}: model {station.model.name} has no resource of it; added a "
                         f"stub resource model and a resource {device_type!r} of it (model it after the device):")
    changes.create(stub, render("device_model.py", type=device_type))
    changes.edit(station.model_file, text, f"resource {device_type!r} added to build_model()")
    reloaded = load_project(station.root)
    if device_type not in reloaded.model.resource_by_name:
        raise ScaffoldError(f"{station.model_file}: the resource {device_type!r} was added but the model does not "
                            f"have it: check build_model()")
    return reloaded


def _entry_point_registered(pyproject: Path, device_type: str, target: str) -> bool:
    """Whether the driver's entry point is there already; one that names another object is left to the
    person (never replaced): ScaffoldError."""
    current = tomllib.loads(pyproject.read_text(encoding="utf-8")).get("project", {}).get(
        "entry-points", {}).get(DRIVER_GROUP, {})
    if device_type in current and current[device_type] != target:
        raise ScaffoldError(f"{pyproject}: entry point {device_type} of group {DRIVER_GROUP} names "
                            f"{current[device_type]!r}, not {target!r}: change it by hand")
    return device_type in current


def _register_entry_point(pyproject: Path, device_type: str, target: str, changes: Changes, registered: bool) -> None:
    if registered:
        changes.lines.append(f"  {changes.rel(pyproject)}: entry point {device_type} = {target!r} is there already")
        return
    text = add_to_table(pyproject.read_text(encoding="utf-8"), ("project", "entry-points", DRIVER_GROUP),
                        [f'{device_type} = "{target}"'], pyproject)
    changes.edit(pyproject, text, f"entry point {device_type} = {target!r} (group {DRIVER_GROUP})")


# The device's table: emulated until the driver is written; the driver's Params (host, port) ready.
COMMENT_COLUMN = 39  # where the comments of hubs.toml's device tables start
DRIVER_PARAMS = [
    f'host = "{PLACEHOLDER_HOST}"'.ljust(COMMENT_COLUMN) + "# TODO: the device's address (the driver's Params)",
    "port = 502",
]


def _device_lines(device_type: str) -> list[str]:
    return [f'type = "{device_type}"', 'mode = "emulate"'.ljust(COMMENT_COLUMN) + '# "real" once the driver is written',
            *DRIVER_PARAMS]


def _add_to_hubs_toml(station: Station, resources: list[Resource], changes: Changes) -> None:
    path = station.root / "hubs.toml"
    text = path.read_text(encoding="utf-8")
    unserved = [r for r in resources if r.name not in station.config.resources]
    for resource in resources:
        if resource.name not in station.config.resources:
            continue
        hub, device = station.config.hub_of(resource.name), station.config.device(resource.name)
        if "host" in device.params:
            changes.lines.append(f"  hubs.toml: {resource.name} is served by hub {hub.name} already (left as it is)")
            continue
        text = add_to_table(text, ("hubs", hub.name, "devices", resource.name), DRIVER_PARAMS, path)
        changes.edit(path, text, f"the driver's parameters for {resource.name} (hub {hub.name})")
    if unserved:
        new_hub = resources[0].device_type
        while new_hub in station.config.hubs:
            new_hub += "_hub"
        machine = f"{new_hub.replace('_', '-')}-ecu.local"  # a host name has no underscores
        host = f'host = "{machine}"'.ljust(COMMENT_COLUMN) + "# TODO: the machine this hub runs on"
        text = text.rstrip("\n") + f"\n\n[hubs.{toml_key((new_hub,))}]\n{host}\n"
        for resource in unserved:
            text += f"\n[{toml_key(('hubs', new_hub, 'devices', resource.name))}]\n"
            text += "".join(f"{line}\n" for line in _device_lines(resource.device_type))
        changes.edit(path, text, f"hub {new_hub} serving {', '.join(r.name for r in unserved)}")
    try:
        check_against_model(load_config(path), station.model)
    except ConfigError as exc:
        changes.lines.append(f"  note: hubs.toml does not fit the model yet: {exc}")
