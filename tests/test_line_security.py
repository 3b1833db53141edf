"""Access control across routers with TLS: two stations of a line, each a client of its own router, the
routers linked; the rogues are zenoh sessions of this test presenting real certificates of the site's CA.

Every case has a control that the same measurement sees when it should (an allowed put arrives, a hub
receives its own station's commands, the line controller's order query is answered), so a "nothing
arrived" cannot come from a broken measurement.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from common.bus.zenoh_config import TlsSettings, zenoh_config
from common.config.hubs_toml import load_config
from common.config.security import SecurityError
from common.line.config import LineConfig, load_line
from common.wire.keys import Keys
from common.wire.messages import decode, encode
from common.wire.orders import ORDERS_KEY, OrdersAction, OrdersReply, OrdersRequest
from deploy.line.certs import issue_line
from deploy.line.processes import router_child, station_children
from deploy.local.supervisor import Child
from deploy.router.security import LINE_CONTROLLER_NAME, check_unique_names
from tests.line_station.site import write_line

ROOT = Path(__file__).resolve().parent.parent
SETTLE_S = 3.0  # a permitted sample crosses both routers well within this on loopback
MARKER = b"not a command: a test's marker"


@dataclass
class Line:
    line: LineConfig
    certs: Path
    keys: dict[str, Keys]
    processes: list[subprocess.Popen[bytes]]
    # Kept until the module's end (dropped, zenoh undeclares a subscriber), then closed: a session left open
    # holds the interpreter's exit.
    sessions: list[zenoh.Session] = field(default_factory=list)
    subscribers: list[object] = field(default_factory=list)


def _wait(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def session(line: Line, name: str, router: str) -> zenoh.Session:
    """A client of `router` presenting `name`'s certificate of the site's CA."""
    certs = line.certs
    tls = TlsSettings(certs / "ca.crt", certs / f"{name}.crt", certs / f"{name}.key", {}, verify_names=False)
    config = zenoh_config("client", connect=line.line.router_endpoints(router), lease_ms=1000, tls=tls)
    deadline = time.monotonic() + 60.0  # the routers are starting (a loaded machine)
    while True:
        try:
            opened = zenoh.open(config)
            line.sessions.append(opened)
            return opened
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def collect(line: Line, session: zenoh.Session, key: str) -> list[bytes]:
    samples: list[bytes] = []
    line.subscribers.append(session.declare_subscriber(key, lambda sample: samples.append(sample.payload.to_bytes())))
    return samples


@pytest.fixture(scope="module")
def tls_line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Line]:
    directory = tmp_path_factory.mktemp("tls_line")
    config = load_line(write_line(directory, 2, tls=True))
    assert config.security.certs is not None
    issue_line(config.security.certs, config)
    run_dir = directory / "run"
    certs = config.security.certs
    children: list[Child] = [router_child(config, r, run_dir, certs) for r in config.routers]
    for name in config.route:
        children += station_children(config.stations[name], run_dir, certs=certs)
    processes = []
    for child in children:
        child.log.parent.mkdir(parents=True, exist_ok=True)
        with child.log.open("wb") as log:
            processes.append(subprocess.Popen([*child.argv, *child.first_start_args], stdout=log,
                                              stderr=subprocess.STDOUT, cwd=ROOT))
    keys = {name: load_config(s.config).keys for name, s in config.stations.items()}
    line = Line(config, config.security.certs, keys, processes)
    try:
        yield line
    finally:
        for opened in line.sessions:
            opened.close()
        for process in processes:
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def test_a_station_controller_commands_only_its_own_station(tls_line: Line) -> None:
    s1, s2 = tls_line.keys["s1"], tls_line.keys["s2"]
    own = collect(tls_line, session(tls_line, "s1-ctl", "r1"), s1.cmd("nr"))
    other = collect(tls_line, session(tls_line, "s2-ctl", "r2"), s2.cmd("nr"))
    rogue = session(tls_line, "s1-ctl", "r1")
    time.sleep(1.0)
    deadline = time.monotonic() + SETTLE_S
    while time.monotonic() < deadline:
        rogue.put(s1.cmd("nr"), MARKER)  # control: its own station's command key
        rogue.put(s2.cmd("nr"), MARKER)
        time.sleep(0.2)
    assert MARKER in own, "the control: s1's controller certificate may command s1"
    _wait(lambda: len(other) > 0, SETTLE_S, "s2's own controller commanding s2 (the control)")
    assert MARKER not in other


def test_the_line_controller_may_ask_for_orders_and_command_nothing(tls_line: Line) -> None:
    s1, s2 = tls_line.keys["s1"], tls_line.keys["s2"]
    observed = collect(tls_line, session(tls_line, "s1-ctl", "r1"), s1.cmd("nr"))
    line_controller = session(tls_line, LINE_CONTROLLER_NAME, "r1")
    time.sleep(1.0)
    for _ in range(10):
        line_controller.put(s1.cmd("nr"), MARKER)
        time.sleep(0.1)
    request = encode(OrdersRequest(action=OrdersAction.LIST, origin="test"))
    for keys in (s1, s2):  # s2 is behind the other router
        answers = [r.ok for r in line_controller.get(keys.ctl(ORDERS_KEY), payload=request, timeout=5.0)]
        payloads = [a.payload.to_bytes() for a in answers if a is not None]
        assert payloads and decode(payloads[0], OrdersReply).accepted
    _wait(lambda: len(observed) > 0, SETTLE_S, "s1's controller commanding s1 (the control)")
    assert MARKER not in observed


def test_a_station_cannot_read_another_stations_commands(tls_line: Line) -> None:
    s2 = tls_line.keys["s2"]
    foreign = collect(tls_line, session(tls_line, "s1-pi-tool", "r1"), s2.cmd("nr"))
    foreign_via_its_router = collect(tls_line, session(tls_line, "s1-pi-tool", "r2"), s2.cmd("nr"))
    own = collect(tls_line, session(tls_line, "s2-pi-tool", "r2"), s2.cmd("nr"))
    _wait(lambda: len(own) >= 10, 2 * SETTLE_S, "s2's hub receiving s2's commands (the control)")
    assert (len(foreign), len(foreign_via_its_router)) == (0, 0)


def test_holder_names_must_be_unique_on_a_line(tmp_path: Path) -> None:
    line = load_line(write_line(tmp_path, 2, tls=True))
    configs = [load_config(s.config) for s in line.stations.values()]
    check_unique_names(configs, line.routers)
    with pytest.raises(SecurityError, match="'s1-pi-tool' is also station"):
        check_unique_names([configs[0], configs[0]], line.routers)
    with pytest.raises(SecurityError, match="'s1-ctl' is also router s1-ctl's"):
        check_unique_names(configs, ["s1-ctl"])
