"""The long-running processes behind `hubctl hub`, `hubctl controller` and `hubctl selftest`."""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
from collections.abc import Mapping
from typing import Any

from common.bus import Bus, zenoh_config_for
from common.config import NetworkConfig, StationConfig, load_station


def setup_logging(name: str, verbose: bool = False) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format=f"%(asctime)s {name} %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("zenoh").setLevel(logging.WARNING)


def stop_on_signals() -> asyncio.Event:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    return stop


def network(config: StationConfig, process: str, loopback_port: int | None) -> NetworkConfig:
    return config.network_for(process) if loopback_port is None else config.loopback_network(process, loopback_port)


async def run_hub(config_path: str, hub: str, *, loopback_port: int | None = None, speed: float = 1.0,
                  seed: int = 0, mode: str | None = None, failure: dict[str, float] | None = None,
                  overrides: Mapping[str, Mapping[str, Any]] | None = None) -> int:
    from hubs.factory import build_drivers
    from hubs.runtime import HubRuntime

    config, model = load_station(config_path)
    settings = config.hubs.get(hub)
    if settings is None:
        raise KeyError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    drivers = build_drivers(config, hub, model, speed=speed, seed=seed, mode=mode, failure=failure,
                            overrides=overrides)
    stop = stop_on_signals()
    async with Bus(zenoh_config_for(network(config, hub, loopback_port))) as bus:
        runtime = HubRuntime(hub=hub, station=config.station.name, model=model, drivers=drivers, bus=bus,
                             rate_hz=settings.rate_hz, command_timeout_s=settings.command_timeout_s)
        logging.getLogger("statehub.hub").info("hub %s serving %s", hub, ", ".join(drivers))
        await runtime.run(stop)
    return 0


async def run_controller(config_path: str, *, loopback_port: int | None = None, db: str | None = None,
                         fresh: bool = False, mirror_wait_s: float = 5.0, hold: bool = False) -> int:
    from pathlib import Path

    from controller.service import ControllerService

    config, model = load_station(config_path)
    db_path = db or config.controller.db
    if fresh:
        for suffix in ("", "-wal", "-shm"):
            Path(db_path + suffix).unlink(missing_ok=True)
    stop = stop_on_signals()
    async with Bus(zenoh_config_for(network(config, "controller", loopback_port))) as bus:
        service = ControllerService(config, model, bus, db=db_path, mirror_wait_s=mirror_wait_s, hold=hold)
        logging.getLogger("statehub.controller").info(
            "controller %s: station %s, %d resources, %d operations", service.controller_id,
            config.station.name, len(service.hubs_of), len(model.operations))
        await service.run(stop)
    return 0


async def run_selftest(config_path: str, hub: str, *, mode: str | None = None,
                       overrides: Mapping[str, Mapping[str, Any]] | None = None) -> int:
    from hubs.factory import build_drivers
    from hubs.selftest import format_report
    from hubs.selftest import run_selftest as selftest

    config, model = load_station(config_path)
    drivers = build_drivers(config, hub, model, mode=mode, overrides=overrides)
    report = await selftest(hub, drivers)
    print(format_report(report))
    return 0 if report.ok else 1
