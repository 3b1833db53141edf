"""Build the drivers of one hub from hubs.toml: emulated from the model, or the real driver (sim/real).

Emulated devices read two optional parameters: `delay` (seconds an effect takes at
speed 1) and `failure_probability` (of the alternative outcomes, e.g. a nutrunner fail).
"""

from __future__ import annotations

import zlib

from common.config import StationConfig
from common.model import Model

from .drivers.base import Driver
from .drivers.emulated import EmulatedDriver


def build_drivers(config: StationConfig, hub: str, model: Model, *, speed: float = 1.0, seed: int = 0,
                  mode: str | None = None, failure: dict[str, float] | None = None) -> dict[str, Driver]:
    """`mode` overrides every device's mode (e.g. `hubctl up --mode sim`); `failure` overrides the
    failure probability of emulated resources."""
    if hub not in config.hubs:
        raise KeyError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    drivers: dict[str, Driver] = {}
    for resource, device in config.hubs[hub].devices.items():
        chosen = mode or device.mode
        if chosen == "emulate":
            params = device.params  # the real device's parameters are ignored when emulating
            drivers[resource] = EmulatedDriver(
                model, resource, speed=speed,
                # a seed per resource: two emulated devices never share one random sequence
                seed=seed ^ zlib.crc32(resource.encode()),
                failure_probability=(failure or {}).get(resource, float(params.get("failure_probability", 0.0))),
                delay=float(params["delay"]) if "delay" in params else None,
            )
        else:
            from .drivers import make_driver

            drivers[resource] = make_driver(resource, device.type, chosen, device.params)
    return drivers
