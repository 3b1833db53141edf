"""Build the drivers of one hub from hubs.toml: emulated from the model, or a driver plugin (sim/real).

Emulated devices read two optional parameters: `delay` (seconds an effect takes at
speed 1) and `failure_probability` (of the alternative outcomes, e.g. a nutrunner fail).
A device in `sim` or `real` mode is built by its type's driver (`hubs.drivers.registry`):
its hubs.toml table, less `type`, `mode` and those two, converted into the driver's
parameter Struct (so a device table may hold both, and switching modes needs no edit).
In `sim` mode the type's simulator (`hubs.sim.registry`) fills in the address of a
simulator at its defaults, or builds the driver wired to a simulator inside the hub
(I2C, CAN).

`overrides` (`hubctl hub --params-file`) are merged into a device's parameters, key by
key: how the simulated world of `hubctl up --mode sim` hands each hub its simulators'
addresses, and how a commissioning engineer tries a parameter without editing hubs.toml.

`real` (`hubctl up --real human`, `hubctl hub --real RESOURCE`) runs the devices it names in mode
real whatever hubs.toml or `--mode` says: the operator's page beside an emulated station.

`check_devices` reports, each with file, line and key, every device in sim or real mode
whose type has no driver, and every parameter its driver does not accept: `hubctl config
check`, `hubctl up` and `hubctl hub` call it before anything starts.
"""

from __future__ import annotations

import json
import tomllib
import zlib
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from common.config.hubs_toml import ConfigError, ConfigProblem, KeyLines, StationConfig, parse_delay
from common.config.modes import DeviceMode, words
from common.model import Model

from .drivers.base import Driver, InStation, StationContext
from .drivers.emulated import EmulatedDriver
from .drivers.params import ParamError, convert_params
from .drivers.registry import ENTRY_POINT_GROUP, builtin_driver_types, find_driver
from .plugins import PluginError
from .sim.registry import find_simulator

Overrides = Mapping[str, Mapping[str, Any]]  # resource -> parameter -> value
Real = Collection[str]  # resources run in mode real whatever hubs.toml or `--mode` says
EMULATION_PARAMS = ("delay", "failure_probability")  # the emulated device's, never a driver's


class NoDriver(LookupError):
    def __init__(self, device_type: str) -> None:
        self.device_type = device_type
        super().__init__(f"no driver for device type {device_type!r}: none is built in "
                         f"({', '.join(builtin_driver_types())}) and no installed package provides one under the "
                         f"entry-point group {ENTRY_POINT_GROUP!r}")


def effective_mode(device_type: str, configured: DeviceMode, override: DeviceMode | None) -> DeviceMode:
    """The mode a device runs in. `--mode sim` leaves the devices whose type has no simulator
    (the operator, the AGV) emulated; a device configured `sim` in hubs.toml is not helped."""
    if override is None:
        return DeviceMode(configured)
    if override == DeviceMode.SIM and find_simulator(device_type) is None:
        return DeviceMode.EMULATE
    return DeviceMode(override)


def chosen_mode(resource: str, device_type: str, configured: DeviceMode, override: DeviceMode | None,
                real: Real = ()) -> DeviceMode:
    """`effective_mode`, unless `real` names the resource: then mode real."""
    return DeviceMode.REAL if resource in real else effective_mode(device_type, configured, override)


def check_real(config: StationConfig, real: Real, hub: str | None = None) -> None:
    """Raise ValueError when `real` names a resource that is no device (of `hub`, or of any hub)."""
    devices = config.hubs[hub].devices if hub is not None else {r for h in config.hubs.values() for r in h.devices}
    unknown = sorted(set(real) - set(devices))
    if unknown:
        where = f"hub {hub!r} serves" if hub is not None else f"{config.path} has"
        raise ValueError(f"--real {', '.join(unknown)}: {where} no such device (devices: {', '.join(sorted(devices))})")


@dataclass(frozen=True)
class DriverSpec:
    """How to build one device's driver: the builder and its checked parameters."""

    build: Callable[[str, Any], Driver]
    params: msgspec.Struct


def resolve(device_type: str, mode: DeviceMode, raw: Mapping[str, Any]) -> DriverSpec:
    """The builder and typed parameters of a device in sim or real mode. Raises NoDriver,
    ParamError (naming the parameter) or PluginError (a plugin that does not load)."""
    plugin = find_driver(device_type)
    if plugin is None:
        raise NoDriver(device_type)
    build, params_type = plugin.build, plugin.params
    raw = {key: value for key, value in raw.items() if key not in EMULATION_PARAMS}
    simulator = find_simulator(device_type) if mode == DeviceMode.SIM else None
    if simulator is not None:
        raw = {**simulator.defaults, **raw}
        if simulator.in_hub is not None:
            build, params_type = simulator.in_hub.build, simulator.in_hub.params
    return DriverSpec(build, convert_params(params_type, raw))


def make_driver(resource: str, device_type: str, mode: DeviceMode | str,
                params: Mapping[str, Any] | None = None) -> Driver:
    """The driver of one resource in sim or real mode (also given as its word: a test, a script).
    Raises ValueError naming what is wrong."""
    if mode not in words(DeviceMode):
        raise ValueError(f"resource {resource!r}: unknown mode {mode!r}; expected one of "
                         f"{', '.join(words(DeviceMode))}")
    mode = DeviceMode(mode)
    if mode == DeviceMode.EMULATE:
        raise ValueError(f"resource {resource!r}: mode 'emulate' is built from the resource model "
                         "(build_drivers, hubs.drivers.emulated), not by make_driver")
    where = f"resource {resource!r} ({device_type}, {mode})"
    try:
        spec = resolve(device_type, mode, params or {})
        return spec.build(resource, spec.params)
    except (NoDriver, PluginError) as exc:
        raise ValueError(f"{where}: {exc}") from exc
    except ParamError as exc:
        raise ValueError(f"{where}: bad parameters: {exc}") from exc
    except (KeyError, TypeError, ValueError) as exc:  # the driver refused what its Struct accepted
        raise ValueError(f"{where}: bad parameters: {exc}") from exc


# --- checking every device before anything starts ----------------------------------------------

def device_problems(config: StationConfig, *, hub: str | None = None, mode: DeviceMode | None = None,
                    overrides: Overrides | None = None, world: bool = False, real: Real = ()) -> list[ConfigProblem]:
    """Devices (of `hub`, or of every hub) in sim or real mode whose type has no driver, or whose
    parameters their driver does not accept; each with file, line and key. `world`: a sim world
    will supply the parameters of the devices it runs a simulator process for (their address,
    the robot's poses), so those may be missing here."""
    path = Path(config.path)
    lines = KeyLines(path.read_text(encoding="utf-8")) if path.is_file() else None
    overrides = overrides or {}
    problems = []
    for hub_config in config.hubs.values():
        if hub is not None and hub_config.name != hub:
            continue
        for resource, device in hub_config.devices.items():
            table = ("hubs", hub_config.name, "devices", resource)
            extra = overrides.get(resource, {})
            chosen = device.mode
            try:
                chosen = chosen_mode(resource, device.type, device.mode, mode, real)
                if chosen != DeviceMode.EMULATE:
                    resolve(device.type, chosen, {**device.params, **extra})
                continue
            except NoDriver as exc:
                key: tuple[str, ...]
                key, message = (*table, "type"), _no_driver(exc, hub_config.name, device.mode, chosen)
            except PluginError as exc:
                key, message = (*table, "type"), str(exc)
            except ParamError as exc:
                if world and exc.missing and _world_supplies(device.type, chosen):
                    continue
                key = (*table, *exc.key.split(".")) if exc.key else table
                origin = " (from the parameter overrides)" if exc.key and exc.key.split(".")[0] in extra else ""
                message = f"{exc.message}{origin} [{device.type} driver, {chosen} mode]"
            line = (lines.line_of(key) if lines else None) or device.line or None
            problems.append(ConfigProblem(config.path, line, ".".join(key), message))
    return problems


def _world_supplies(device_type: str, mode: DeviceMode) -> bool:
    simulator = find_simulator(device_type) if mode == DeviceMode.SIM else None
    return simulator is not None and simulator.server is not None


def _no_driver(exc: NoDriver, hub: str, configured: DeviceMode, chosen: DeviceMode) -> str:
    how = f"mode '{chosen}'" if configured == chosen else f"mode '{chosen}' (--mode {chosen})"
    return (f"{exc} (device in hub {hub!r}, {how}); install the package that provides it, or run the device in "
            f"mode 'emulate' (from the station model)")


def check_devices(config: StationConfig, *, hub: str | None = None, mode: DeviceMode | None = None,
                  overrides: Overrides | None = None, world: bool = False, real: Real = ()) -> None:
    """Raise ConfigError listing every problem `device_problems` finds."""
    problems = device_problems(config, hub=hub, mode=mode, overrides=overrides, world=world, real=real)
    if problems:
        raise ConfigError(problems)


# --- parameter overrides -----------------------------------------------------------------------

def load_overrides(path: str | Path) -> dict[str, dict[str, Any]]:
    """A parameter-override file: JSON, or TOML when it ends in `.toml`; `{resource: {key: value}}`.
    Raises ValueError naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except OSError as exc:
        raise ValueError(f"parameter overrides {path}: cannot read: {exc.strerror or exc}") from exc
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"parameter overrides {path}: invalid {'TOML' if path.suffix == '.toml' else 'JSON'}: "
                         f"{exc}") from exc
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ValueError(f"parameter overrides {path}: expected {{resource: {{parameter: value}}}}")
    return data


def check_overrides(config: StationConfig, hub: str, overrides: Overrides) -> None:
    devices = config.hubs[hub].devices
    unknown = sorted(set(overrides) - set(devices))
    if unknown:
        raise ValueError(f"parameter overrides for {', '.join(unknown)}: hub {hub!r} serves no such resource "
                         f"(its resources: {', '.join(devices)})")
    for resource, params in overrides.items():
        if not isinstance(params, Mapping):
            raise ValueError(f"parameter overrides for {resource!r} must be a table of parameters, "
                             f"not {type(params).__name__}")
        reserved = sorted({"type", "mode"} & set(params))
        if reserved:
            raise ValueError(f"parameter overrides for {resource!r}: {', '.join(reserved)} cannot be overridden "
                             f"(use --mode)")


# --- the drivers of one hub --------------------------------------------------------------------

def build_drivers(config: StationConfig, hub: str, model: Model, *, speed: float = 1.0, seed: int = 0,
                  mode: DeviceMode | None = None, failure: dict[str, float] | None = None,
                  overrides: Overrides | None = None, certs: str | None = None, real: Real = (),
                  emulated_state: Path | None = None) -> dict[str, Driver]:
    """`mode` overrides every device's mode (e.g. `hubctl up --mode sim`), `real` names devices run in mode
    real whatever hubs.toml or `mode` says; `failure` overrides the
    failure probability of emulated resources; `overrides` are merged into the devices' parameters;
    `certs`: the certificate directory given on the command line (a driver serving TLS reads it);
    `emulated_state`: a directory where each emulated device keeps its values across restarts of its hub.
    Raises ConfigError (file, line, key) for a device without driver or with a bad parameter."""
    if hub not in config.hubs:
        raise KeyError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    overrides = overrides or {}
    check_overrides(config, hub, overrides)
    check_real(config, real, hub)
    check_devices(config, hub=hub, mode=mode, overrides=overrides, real=real)
    drivers: dict[str, Driver] = {}
    for resource, device in config.hubs[hub].devices.items():
        chosen = chosen_mode(resource, device.type, device.mode, mode, real)
        params = {**device.params, **overrides.get(resource, {})}
        if chosen == DeviceMode.EMULATE:
            # the real device's parameters are ignored when emulating
            drivers[resource] = EmulatedDriver(
                model, resource, speed=speed,
                # a seed per resource: two emulated devices never share one random sequence
                seed=seed ^ zlib.crc32(resource.encode()),
                failure_probability=(failure or {}).get(resource, float(params.get("failure_probability", 0.0))),
                delay=parse_delay(params["delay"]) if "delay" in params else device.delay,
                keep_in=None if emulated_state is None else emulated_state / f"{resource}.json",
            )
        else:
            driver = make_driver(resource, device.type, chosen, params)
            if isinstance(driver, InStation):
                driver.join_station(StationContext(model, config, hub, certs))
            drivers[resource] = driver
    return drivers
