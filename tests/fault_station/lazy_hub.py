"""A faulty hub for the fault tests: it receives every command but applies only the first N.

    python tests/fault_station/lazy_hub.py HUB --config hubs.toml --loopback-port P [--speed S] [--apply N]

It is the real `HubRuntime` with the real (emulated) drivers, except for what happens
to a command: the first N (default 1) it receives are applied and mirrored as usual;
every later one is received (the hub stays alive, publishes fresh states with status
`ok`, and never falls into its safe state), but neither written to the device nor
mirrored. So its state keeps a stale mirror (or none, with `--apply 0`): a hub whose
outputs silently stopped following the controller, which only the mirror-watchdog
can notice.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config_for
from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import network, setup_logging, stop_on_signals
from common.wire.messages import HubStatus, MessageError
from hubs.factory import build_drivers
from hubs.runtime import HubRuntime, ResourceSlot

log = logging.getLogger("statehub.hub")


class LazyHubRuntime(HubRuntime):
    apply = 1  # commands applied before it stops applying
    received = 0

    async def _commands(self, slot: ResourceSlot) -> None:
        async for sample in self.bus.subscribe(self.keys.cmd(slot.name)):
            try:
                command = slot.codec.decode_command(sample.payload)
            except MessageError:
                continue
            self.received += 1
            slot.last_command_at = time.monotonic()  # it did receive it: no safe state
            slot.in_safe_state = False
            slot.status, slot.detail = HubStatus.OK, ""
            if self.received <= self.apply:
                # A command carries every command variable: none is unknown (None) as a measured one may be.
                values = {name: v for name, v in slot.codec.values(command).items() if v is not None}
                await slot.driver.write(values)
                slot.mirror = command
                log.info("lazy hub %s: applied command %d of %d to %s (seq %d)", self.hub, self.received,
                         self.apply, slot.name, command.seq)
            elif self.received == self.apply + 1:
                log.info("lazy hub %s: from now on commands are received but not applied", self.hub)
            self._publish(slot)


async def main(args: argparse.Namespace) -> int:
    config, model = load_station(args.config)
    settings = config.hubs[args.hub]
    drivers = build_drivers(config, args.hub, model, speed=args.speed)
    stop = stop_on_signals()
    async with ZenohBus(zenoh_config_for(network(config, args.hub, args.loopback_port))) as bus:
        runtime = LazyHubRuntime(hub=args.hub, station=config.station.name, model=model, drivers=drivers, bus=bus,
                                 rate_hz=settings.rate_hz, command_timeout_s=settings.command_timeout_s)
        runtime.apply = args.apply
        log.info("lazy hub %s serving %s", args.hub, ", ".join(drivers))
        await runtime.run(stop)
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("hub")
    parser.add_argument("--config", required=True)
    parser.add_argument("--loopback-port", type=int, required=True)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--apply", type=int, default=1, help="commands applied before it stops applying")
    arguments = parser.parse_args()
    setup_logging(f"lazy-{arguments.hub}")
    sys.exit(asyncio.run(main(arguments)))
