"""`hubctl deploy`'s last step: waiting for the restarted hub over Zenoh on loopback.

The station's layout: a controller-like peer listens, the hub connects to it and
listens nowhere. The watcher connects to the controller as the hub does and listens on
a free port, so that gossip brings the hub to it.
"""

from __future__ import annotations

import asyncio
import sys

import pytest

from common.bus.protocol import Bus, Request
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config, zenoh_config_for
from common.config.hubs_toml import parse_config
from common.plumbing.lifecycle import free_port
from common.wire.keys import station_keys
from common.wire.messages import encode
from deploy.remote.deploy import Waiting, wait_step
from deploy.remote.hubwait import HubWaitError, HubWatch, watch_config, watch_endpoints
from deploy.remote.progress import Progress, StepFailed
from hubs.drivers.base import SelftestReport
from hubs.selftest import report_message
from tests.deploy_support import REPO, station_toml

pytestmark = pytest.mark.timeout(60)


def report(ok: bool) -> bytes:
    nr = SelftestReport("nr")
    nr.add("device answers", True)
    nr.add("outputs read back", ok, "" if ok else "run_c reads back false")
    return encode(report_message("pi-tool", [nr]))


async def start_hub(bus: Bus, station: str, payload: bytes) -> None:
    """What hubs/runtime.py does at start: token, then the self-test report (published and queryable)."""
    keys = station_keys(station)
    bus.declare_liveliness(keys.alive("pi-tool"))
    bus.publish(keys.selftest("pi-tool"), payload, block=True)

    async def answer(_request: Request) -> bytes:
        return payload

    bus.declare_queryable(keys.selftest("pi-tool"), answer)


@pytest.fixture
def station():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    return endpoint, parse_config(station_toml(connect=[endpoint]), "hubs.toml")


async def test_the_restarted_hub_is_seen_with_its_report(station):
    endpoint, config = station
    async with ZenohBus(zenoh_config("peer", listen=[endpoint])):  # the controller
        zconfig = watch_config(config, "pi-tool", listen="tcp/127.0.0.1:0")
        async with ZenohBus(zconfig) as bus, HubWatch(bus, config.station.name, "pi-tool") as watch:
            watch.restarted()
            async with ZenohBus(zenoh_config_for(config.network_for("pi-tool"))) as hub:
                await start_hub(hub, config.station.name, report(ok=True))
                seen = await watch.wait(timeout=20)
    assert seen.hub == "pi-tool" and seen.ok and [d.resource for d in seen.devices] == ["nr"]


async def test_a_failed_self_test_fails_the_step(station):
    endpoint, config = station
    progress = Progress(1)
    async with ZenohBus(zenoh_config("peer", listen=[endpoint])):
        zconfig = watch_config(config, "pi-tool", listen="tcp/127.0.0.1:0")
        async with ZenohBus(zconfig) as bus, HubWatch(bus, config.station.name, "pi-tool") as watch:
            watch.restarted()
            async with ZenohBus(zenoh_config_for(config.network_for("pi-tool"))) as hub:
                await start_hub(hub, config.station.name, report(ok=False))
                with pytest.raises(StepFailed) as failed:
                    await wait_step(progress, watch, "pi-tool", Waiting(timeout=20))
    message = str(failed.value.cause)
    assert "hub pi-tool is alive but its self-test FAILED" in message
    assert "[FAIL] outputs read back: run_c reads back false" in message


async def test_a_hub_that_never_comes_says_so(station):
    endpoint, config = station
    async with ZenohBus(zenoh_config("peer", listen=[endpoint])):
        zconfig = watch_config(config, "pi-tool", listen="tcp/127.0.0.1:0")
        async with ZenohBus(zconfig) as bus, HubWatch(bus, config.station.name, "pi-tool") as watch:
            watch.restarted()
            with pytest.raises(HubWaitError) as failed:
                await watch.wait(timeout=1.5)
    assert "hub pi-tool did not come up on zenoh within 2 s: no liveliness token and no self-test report" \
           in str(failed.value)
    assert "engine_assembly/hub/pi-tool/alive" in str(failed.value)
    assert "journalctl -u statehub-hub-pi-tool" in str(failed.value)


async def test_a_real_hub_process_is_seen(station, tmp_path):
    """Against the hub process itself (`python -m hubs`, emulated devices), what a hub's unit runs."""
    endpoint, config = station
    path = tmp_path / "hubs.toml"
    path.write_text(station_toml(connect=[endpoint]))
    async with ZenohBus(zenoh_config("peer", listen=[endpoint])):
        zconfig = watch_config(config, "pi-tool", listen="tcp/127.0.0.1:0")
        async with ZenohBus(zconfig) as bus, HubWatch(bus, config.station.name, "pi-tool") as watch:
            watch.restarted()
            hub = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "hubs", "pi-tool", "--config", str(path), cwd=REPO,
                stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
            try:
                seen = await watch.wait(timeout=30)
            finally:
                hub.terminate()
                _out, err = await hub.communicate()
    assert seen.ok, err.decode()
    assert sorted(d.resource for d in seen.devices) == ["lift", "nr"]


def test_the_watcher_connects_where_the_hub_connects_or_listens():
    text = station_toml(connect=["tcp/decs.local:7447"])
    text = text.replace('[hubs.pi-rsp]\n', '[hubs.pi-rsp]\nlisten = ["tcp/0.0.0.0:7448"]\nconnect = []\n')
    config = parse_config(text, "hubs.toml")
    assert watch_endpoints(config, "pi-tool") == ["tcp/decs.local:7447"]
    assert watch_endpoints(config, "pi-rsp") == ["tcp/pi-rsp.local:7448"]


def test_waiting_is_skipped_without_a_watch(capsys):
    asyncio.run(wait_step(Progress(1), None, "pi-tool", Waiting(wait=False)))
    assert "[1/1] wait for hub pi-tool on zenoh (liveliness, self-test) ... ok" in capsys.readouterr().out
