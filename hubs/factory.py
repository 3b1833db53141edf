"""Build the drivers of one hub from hubs.toml: emulated from the model, or the real driver (sim/real).

Emulated devices read two optional parameters: `delay` (seconds an effect takes at
speed 1) and `failure_probability` (of the alternative outcomes, e.g. a nutrunner fail).

`overrides` (`hubctl hub --params-file`) are merged into a device's parameters, key by
key: how the simulated world of `hubctl up --mode sim` hands each hub its simulators'
addresses, and how a commissioning engineer tries a parameter without editing hubs.toml.
"""

from __future__ import annotations

import json
import tomllib
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.config import StationConfig
from common.model import Model

from .drivers.base import Driver
from .drivers.emulated import EmulatedDriver

Overrides = Mapping[str, Mapping[str, Any]]  # resource -> parameter -> value


def effective_mode(device_type: str, configured: str, override: str | None) -> str:
    """The mode a device runs in. `--mode sim` leaves the devices with no protocol simulator
    (the operator, the AGV) emulated; a device configured `sim` in hubs.toml is not helped."""
    if override is None:
        return configured
    if override == "sim":
        from .drivers import device_types

        if device_type not in device_types():
            return "emulate"
    return override


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


def build_drivers(config: StationConfig, hub: str, model: Model, *, speed: float = 1.0, seed: int = 0,
                  mode: str | None = None, failure: dict[str, float] | None = None,
                  overrides: Overrides | None = None) -> dict[str, Driver]:
    """`mode` overrides every device's mode (e.g. `hubctl up --mode sim`); `failure` overrides the
    failure probability of emulated resources; `overrides` are merged into the devices' parameters."""
    if hub not in config.hubs:
        raise KeyError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    overrides = overrides or {}
    check_overrides(config, hub, overrides)
    drivers: dict[str, Driver] = {}
    for resource, device in config.hubs[hub].devices.items():
        chosen = effective_mode(device.type, device.mode, mode)
        params = {**device.params, **overrides.get(resource, {})}
        if chosen == "emulate":
            # the real device's parameters are ignored when emulating
            drivers[resource] = EmulatedDriver(
                model, resource, speed=speed,
                # a seed per resource: two emulated devices never share one random sequence
                seed=seed ^ zlib.crc32(resource.encode()),
                failure_probability=(failure or {}).get(resource, float(params.get("failure_probability", 0.0))),
                delay=float(params["delay"]) if "delay" in params else None,
            )
        else:
            from .drivers import make_driver

            drivers[resource] = make_driver(resource, device.type, chosen, params)
    return drivers
