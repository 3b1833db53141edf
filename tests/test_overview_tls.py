"""The overview's certificate in `[security] mode = "tls"`: the viewer role reads everything the page needs and
can command nothing. The fault station's controller and hubs run as processes with TLS and access control on;
the test's sessions present the viewer's certificate (`[overview] name`), as `hubctl overview` does."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from common.bus.station_net import station_zenoh_config
from common.bus.zenoh_bus import ZenohBus
from common.config.hubs_toml import StationConfig, load_station
from common.config.security import identity_of, viewer_identity
from common.model import Model
from common.plumbing.lifecycle import free_port
from common.wire.ctl import ConsoleRequest
from common.wire.messages import encode
from controller.overview.reader import StationReader
from deploy.certs import init_ca, issue_for_station
from tests.hub_process import HubProcess

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

ROOT = Path(__file__).resolve().parent.parent
FAULT_STATION = ROOT / "tests" / "fault_station" / "hubs.toml"


@dataclass
class Secured:
    config: StationConfig
    model: Model
    port: int
    certs: Path

    def zconfig(self, name: str, *, own_checks: bool = True) -> zenoh.Config:
        base = self.config.loopback_network("controller", self.port)
        identity = viewer_identity(self.config) if name == "overview" else identity_of(self.config, name)
        zconfig = station_zenoh_config(self.config, self.model, identity, base, certs=self.certs,
                                       connect=base.listen, listen=[])
        if not own_checks:  # what stops it must be the station's processes, not its own configuration
            zconfig.insert_json5("access_control", '{"enabled": false}')
        return zconfig


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Secured]:
    text = FAULT_STATION.read_text().replace('name = "fault_station"', f'name = "overview_tls_{free_port()}"')
    path = tmp_path / "hubs.toml"
    path.write_text(f'{text}\n[security]\nmode = "tls"\noperators = ["op"]\n', encoding="utf-8")
    config, model = load_station(path)
    certs = tmp_path / "certs"
    init_ca(certs, config.station.name, force=True)
    issue_for_station(certs, config, [identity_of(config, n) for n in ("controller", "pi-tool", "ur10", "op",
                                                                       "overview")])
    port = free_port()
    with (tmp_path / "controller.log").open("wb") as log:
        controller = subprocess.Popen(
            [sys.executable, "-m", "controller", "--config", str(path), "--loopback-port", str(port), "--certs",
             str(certs), "--db", str(tmp_path / "controller.sqlite"), "--fresh", "--mirror-wait", "1"],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    hubs = [HubProcess(path, hub, port, tmp_path / f"{hub}.log", "--certs", str(certs)).start()
            for hub in ("pi-tool", "ur10")]
    try:
        yield Secured(config, model, port, certs)
    finally:
        for hub in hubs:
            hub.stop()
        controller.terminate()
        controller.wait(10)
        print((tmp_path / "controller.log").read_text(errors="replace")[-3000:])


async def test_the_viewer_reads_the_status_and_the_plans(secured: Secured) -> None:
    async with ZenohBus(secured.zconfig("overview")) as bus:
        reader = StationReader(bus, secured.config.keys)
        deadline = time.monotonic() + 60
        while True:
            status = await reader.full_status()
            if status is not None and status.finished:
                break
            assert time.monotonic() < deadline, f"the station did not finish for the viewer: {status}"
            await asyncio.sleep(0.5)
        assert {op.name for op in status.operations} == {f"TightenBolt{i}" for i in (1, 2, 3, 4)}
        assert status.plans >= 1
        first = await reader.plan(1)  # the controller keeps answering for plans it has dropped
        assert first is not None and first.steps, "the viewer may ask the controller's plans"


def test_the_viewer_can_neither_request_nor_command(secured: Secured) -> None:
    keys = secured.config.keys
    request = encode(ConsoleRequest(action="resume", origin="overview test"))

    def answers(name: str) -> tuple[int, int]:
        """(status samples received, replies to 3 requests) of a session presenting `name`'s certificate,
        asked once it receives the controller's status: its link is up."""
        session = zenoh.open(secured.zconfig(name, own_checks=False))
        statuses: list[object] = []
        try:
            session.declare_subscriber(keys.ctl("status"), statuses.append)
            deadline = time.monotonic() + 30
            while not statuses and time.monotonic() < deadline:
                time.sleep(0.1)
            replies = sum(len(list(session.get(keys.ctl("request"), payload=request, timeout=2.0)))
                          for _ in range(3))
            return len(statuses), replies
        finally:
            session.close()

    heard, answered = answers("op")
    assert heard and answered == 3, "the operator's requests are answered (the check can fail)"
    heard, answered = answers("overview")
    assert heard, "the viewer receives the controller's status"
    assert answered == 0, "the controller answered the viewer's request"
