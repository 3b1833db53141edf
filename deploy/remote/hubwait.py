"""Waiting, over the station's Zenoh network, for a restarted hub: its liveliness token and self-test report.

The watch opens *before* the restart: the new process publishes its self-test report
once, at start, and a subscriber declared afterwards could miss it. A report seen after
`restarted()` comes from the new process (a running hub never republishes it); as a
fallback the hub's self-test queryable is asked every second.

Reaching the hub: in peer mode a hub connects to the controller and listens nowhere, and
a peer does not relay between two others, so a watcher that merely connected to the
controller would never see the hub. The watcher therefore also listens (by default on
an ephemeral port on every interface): gossip tells the hub about it and the hub
connects to it directly. In client mode the routers relay and no listener is needed.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass

from common.bus.protocol import Bus, LivelinessEvent, Sample, Subscription
from common.bus.zenoh_config import ZenohConfig, zenoh_config
from common.config.hubs_toml import StationConfig
from common.config.modes import NetworkMode, SecurityMode
from common.wire.keys import station_keys
from common.wire.messages import MessageError, decode
from common.wire.selftest_report import SelftestMessage

DEFAULT_LISTEN = "tcp/0.0.0.0:0"
_WILDCARD_HOSTS = ("0.0.0.0", "[::]", "::")


class HubWaitError(RuntimeError):
    pass


def watch_endpoints(config: StationConfig, hub: str) -> list[str]:
    """Where the watcher connects: the hub's connect endpoints, plus the hub's own listeners
    (a wildcard address replaced by the hub's host)."""
    net = config.network_for(hub)
    endpoints = list(net.connect)
    host = config.hubs[hub].host
    for endpoint in net.listen:
        proto, _, address = endpoint.partition("/")
        hostpart, _, port = address.rpartition(":")
        if hostpart in _WILDCARD_HOSTS:
            endpoints.append(f"{proto}/{host}:{port}")
        else:
            endpoints.append(endpoint)
    return endpoints


def watch_config(config: StationConfig, hub: str, *, listen: str = DEFAULT_LISTEN,
                 connect: list[str] | None = None) -> ZenohConfig:
    """The watcher's session: in [security] mode "tls" with the first operator's certificate."""
    net = config.network_for(hub)
    endpoints = connect or watch_endpoints(config, hub)
    if config.security.mode == SecurityMode.TLS:
        from common.bus.station_net import station_zenoh_config
        from common.config.security import operator_identity

        return station_zenoh_config(config, config.load_model(), operator_identity(config), net,
                                    listen=[listen] if listen and net.mode == NetworkMode.PEER else [],
                                    connect=endpoints)
    if net.mode == NetworkMode.CLIENT:
        return zenoh_config(NetworkMode.CLIENT, connect=endpoints, lease_ms=net.lease_ms)
    return zenoh_config(NetworkMode.PEER, listen=[listen] if listen else [], connect=endpoints, lease_ms=net.lease_ms)


@dataclass
class HubWatch:
    bus: Bus
    station: str
    hub: str

    def __post_init__(self) -> None:
        self.keys = station_keys(self.station)
        self._reports: Subscription[Sample] | None = None
        self._alive: Subscription[LivelinessEvent] | None = None

    async def __aenter__(self) -> HubWatch:
        self._reports = self.bus.subscribe(self.keys.selftest(self.hub), coalesce=False)
        self._alive = self.bus.watch_liveliness(self.keys.alive(self.hub))
        return self

    async def __aexit__(self, *_exc: object) -> None:
        for sub in (self._reports, self._alive):
            if sub is not None:
                sub.close()

    def restarted(self) -> None:
        """Call right before the restart: what was seen until now belongs to the old process."""
        assert self._reports is not None and self._alive is not None
        self._reports.take_all()
        self._alive.take_all()

    async def wait(self, timeout: float) -> SelftestMessage:
        """The new process's self-test report once the hub is alive; HubWaitError after `timeout`."""
        assert self._reports is not None and self._alive is not None
        deadline = time.monotonic() + timeout
        report: SelftestMessage | None = None
        alive_seen = False
        next_query = time.monotonic() + 1.0
        while True:
            for event in self._alive.take_all():
                alive_seen = event.alive
            if report is None:
                for sample in self._reports.take_all():
                    report = self._decode(sample.payload)
            if report is None and time.monotonic() >= next_query:
                next_query = time.monotonic() + 1.0
                for reply in await self.bus.get(self.keys.selftest(self.hub), timeout=0.5):
                    if reply.ok:
                        report = self._decode(reply.payload)
            # The report comes from the new process, which declares its token before it
            # runs the self-test: confirm the token (an old one may just be expiring).
            if report is not None and (alive_seen or await self.bus.alive_tokens(self.keys.alive(self.hub),
                                                                                   timeout=0.5)):
                return report
            if time.monotonic() >= deadline:
                state = ("alive, but sent no self-test report" if alive_seen
                         else "no liveliness token and no self-test report")
                raise HubWaitError(f"hub {self.hub} did not come up on zenoh within {timeout:.0f} s: {state} "
                                   f"(key {self.keys.alive(self.hub)}); see `journalctl -u statehub-hub-{self.hub}` "
                                   f"on its host")
            await asyncio.sleep(0.1)

    def _decode(self, payload: bytes) -> SelftestMessage:
        try:
            return decode(payload, SelftestMessage)
        except MessageError as exc:
            raise HubWaitError(f"hub {self.hub}: unreadable self-test report on {self.keys.selftest(self.hub)}: "
                               f"{exc}") from None
