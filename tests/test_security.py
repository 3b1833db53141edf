"""[security] mode = "tls" against rogue peers: the real controller and a real hub as processes, on loopback.

The station is hubs.toml with TLS on and a 500 ms lease; the controller (`--hold`: it
commands the initial values and starts nothing) and hub pi-tool run as processes with
certificates of the station's CA (deploy/certs.py). The rogues are zenoh sessions of this
test process. Every case has a control that the same measurement sees when it should
(a legitimate session links, an allowed put arrives, an operator gets its reply), so a
"nothing arrived" cannot come from a broken measurement. The figures are in README.md.
"""

from __future__ import annotations

import json
import re
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zenoh

from common.bus.station_net import station_zenoh_config
from common.bus.zenoh_config import zenoh_config
from common.config.acl import access_control
from common.config.hubs_toml import ConfigError, StationConfig, load_station
from common.config.security import SecurityError, identity_of, tls_files
from common.model import Model
from common.plumbing.lifecycle import free_port
from common.wire.ctl import ConsoleRequest, StateSnapshot, StatusMessage
from common.wire.messages import Codec, HubStatus, decode, encode
from deploy.certs import identities_for, init_ca, issue, issue_for_station, role_in_certificate
from deploy.remote.deploy import hub_cert_files
from deploy.remote.layout import Layout
from deploy.remote.scripts import install_unit
from deploy.remote.units import controller_unit, hub_unit
from tests.hub_process import HubProcess

ROOT = Path(__file__).resolve().parent.parent
ATTEMPTS = 10  # rogue sessions per kind of attack
SETTLE_S = 2.0  # a legitimate session links and gets its first samples well within this on loopback
FORGED_SEQ = 2**62


@dataclass
class Station:
    config: StationConfig
    model: Model
    port: int
    certs: Path
    rogue_ca: Path
    controller: subprocess.Popen[bytes]
    hub: HubProcess
    status: StatusMessage | None = None
    samples: dict[str, list[bytes]] = field(default_factory=dict)

    def session(self, name: str, certs: Path | None = None, *, listen: bool = False,
                rogue: bool = True) -> zenoh.Session:
        """A session presenting `name`'s certificate from `certs` (default: the station's), connecting to the
        controller (and listening on a free port, as the hubs do, when `listen`). A rogue's checks nothing
        itself: whatever stops it is the access control of the station's processes."""
        base = self.config.loopback_network("controller", self.port)
        zconfig = station_zenoh_config(self.config, self.model, identity_of(self.config, name), base,
                                       certs=certs or self.certs, connect=base.listen,
                                       listen=["tls/127.0.0.1:0"] if listen else [])
        if rogue:
            zconfig.insert_json5("access_control", json.dumps({"enabled": False}))
        return zenoh.open(zconfig)


def _with_security(body: str) -> str:
    """The reference hubs.toml with `body` as its [security] section."""
    text = (ROOT / "hubs.toml").read_text(encoding="utf-8")
    text, replaced = re.subn(r"(?ms)^\[security\]\n.*?(?=^(\[|# ---))", "", text)
    assert replaced == 1, "hubs.toml has no [security] section to replace"
    return f"{text}\n[security]\n{body}\n"


def _station_file(tmp: Path) -> Path:
    text = _with_security('mode = "tls"\noperators = ["op"]')
    text = re.sub(r"(?m)^lease_ms = \d+", "lease_ms = 500", text)
    # pi-tool publishes its state at 2 Hz (and on change), so that a forged state sent at 20 Hz would be
    # most of what the controller sees of nr, and show in its snapshots, were it let through.
    text = re.sub(r"(?m)^rate_hz = 50$", "rate_hz = 2", text, count=1)
    path = tmp / "hubs.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _collector(samples: dict[str, list[bytes]], key: str) -> Callable[[zenoh.Sample], None]:
    """Keep each sample's payload under `key` (the key appears with its first sample)."""
    return lambda sample: samples.setdefault(key, []).append(bytes(sample.payload.to_bytes()))


def _wait(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(0.05)


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Station]:
    tmp = tmp_path_factory.mktemp("secure_station")
    path = _station_file(tmp)
    config, model = load_station(path)
    certs, rogue_ca = tmp / "certs", tmp / "rogue-ca"
    init_ca(certs, config.station.name, force=True)
    issue_for_station(certs, config, [identity_of(config, n) for n in ("controller", "pi-tool", "pi-rsp", "op")])
    init_ca(rogue_ca, config.station.name, force=True)  # another CA, same station name and holder names
    for identity in (identity_of(config, "controller"), identity_of(config, "pi-tool")):
        issue(rogue_ca, identity, ["127.0.0.1"], force=True)
    port = free_port()
    with (tmp / "controller.log").open("wb") as log:
        controller = subprocess.Popen(
            [sys.executable, "-m", "controller", "--config", str(path), "--loopback-port", str(port), "--certs",
             str(certs), "--db", str(tmp / "controller.sqlite"), "--fresh", "--hold", "--mirror-wait", "1"],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    hub = HubProcess(path, "pi-tool", port, tmp / "pi-tool.log", "--certs", str(certs)).start()
    station = Station(config, model, port, certs, rogue_ca, controller, hub)
    observer = station.session("op", rogue=False)  # a console: reads status, states and the global state
    keys = config.keys
    for key in (keys.state("nr"), keys.state("rsp"), keys.ctl("state"), keys.ctl("status")):
        observer.declare_subscriber(key, _collector(station.samples, key))
    try:
        codec = Codec(model.resource_by_name["nr"])
        _wait(lambda: any(codec.decode_state(p).mirror is not None for p in station.samples.get(keys.state("nr"), []))
              and keys.ctl("status") in station.samples, 30,
              f"hub pi-tool applying the controller's commands, the controller's status (logs in {tmp})")
        station.status = decode(station.samples[keys.ctl("status")][-1], StatusMessage)
        yield station
    finally:
        observer.close()
        hub.stop()
        controller.terminate()
        controller.wait(timeout=10)


def _plain_tcp_session(port: int) -> zenoh.Session:
    return zenoh.open(zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"]))


def _tls_session_without_certificate(station: Station) -> zenoh.Session:
    zconfig = zenoh_config("peer", connect=[f"tls/127.0.0.1:{station.port}"])
    tls = {"root_ca_certificate": str(station.certs / "ca.crt"), "enable_mtls": True}
    zconfig.insert_json5("transport/link/tls", json.dumps(tls))
    return zenoh.open(zconfig)


def _attempts(opens: Callable[[], zenoh.Session], station: Station, *, control: bool = False) -> tuple[int, int]:
    """ATTEMPTS rogue sessions at once, each subscribing to the station's states and `ctl/**` and
    forging a command for SETTLE_S: (how many linked to anyone, how many samples of the station they
    received). The `control` keeps waiting (10 s at most) for all to link: a loaded machine is slow."""
    keys = station.config.keys
    received: list[zenoh.Sample] = []
    with ThreadPoolExecutor(ATTEMPTS) as pool:  # zenoh.open waits on its first connection: open them at once
        sessions = list(pool.map(lambda _: opens(), range(ATTEMPTS)))
    try:
        for session in sessions:
            for key in (keys.all_state, keys.ctl("**")):  # what a console may read
                session.declare_subscriber(key, received.append)
        deadline = time.monotonic() + SETTLE_S
        while time.monotonic() < deadline:
            for session in sessions:
                session.put(keys.cmd("nr"), b"forged")
            time.sleep(0.1)
        if control:
            _wait(lambda: all(list(s.info.peers_zid()) for s in sessions) and bool(received), 10, "the control")
        return sum(1 for s in sessions if list(s.info.peers_zid())), len(received)
    finally:
        for session in sessions:
            session.close()


def test_peers_without_a_certificate_of_the_station_cannot_link(station: Station) -> None:
    rogue_controller = identity_of(station.config, "controller")
    outcomes = {
        "plain tcp": _attempts(lambda: _plain_tcp_session(station.port), station),
        "tls, no certificate": _attempts(lambda: _tls_session_without_certificate(station), station),
        "tls, another CA's certificate named as the controller": _attempts(
            lambda: station.session(rogue_controller.name, station.rogue_ca), station),
    }
    # The control: the same measurement with the station's own operator certificate links and receives.
    linked, received = _attempts(lambda: station.session("op"), station, control=True)
    print(f"figures: {ATTEMPTS} attempts each, (linked, samples received): {outcomes}; "
          f"operator certificate (control): ({linked}, {received})")
    assert linked == ATTEMPTS and received > 0, "the measurement does not see a legitimate session"
    assert outcomes == dict.fromkeys(outcomes, (0, 0)), outcomes
    assert station.hub.alive() and station.controller.poll() is None


def test_a_hubs_certificate_can_forge_no_command_and_no_other_resources_state(station: Station) -> None:
    keys, model = station.config.keys, station.model
    nr, rsp = Codec(model.resource_by_name["nr"]), Codec(model.resource_by_name["rsp"])
    assert station.status is not None
    # pi-rsp's own certificate, used by something that is not pi-rsp: it links, and tries everything.
    rogue = station.session("pi-rsp", listen=True)
    forged_command = nr.encode_command(nr.command({"run_c": True}, seq=FORGED_SEQ,
                                                  controller=station.status.controller))
    stolen: list[bytes] = []  # the controller's commands to pi-tool, had the rogue been sent them

    def steal(sample: zenoh.Sample) -> None:
        if (payload := bytes(sample.payload.to_bytes())) != forged_command:  # not its own, delivered locally
            stolen.append(payload)

    rogue.declare_subscriber(keys.cmd("nr"), steal)
    rogue.declare_subscriber(keys.all_cmd, steal)
    rogue.liveliness().declare_token(keys.alive("pi-tool"))
    forged_state = nr.encode_state(nr.state({"run_m": True, "tqr_m": True, "fail_m": True}, status=HubStatus.OK,
                                            seq=FORGED_SEQ, hub="pi-tool"))
    own_state = rsp.encode_state(rsp.state({"locked_m": True, "tool_m": "none", "pressure_ok_m": True},
                                           status=HubStatus.OK, seq=1, hub="pi-rsp"))
    seen = {k: len(station.samples.get(k, [])) for k in (keys.state("nr"), keys.state("rsp"), keys.ctl("state"))}
    deadline, forged = time.monotonic() + SETTLE_S, 0
    while time.monotonic() < deadline:
        rogue.put(keys.cmd("nr"), forged_command)
        rogue.put(keys.state("nr"), forged_state)
        rogue.put(keys.state("rsp"), own_state)  # allowed: pi-rsp's own state
        forged += 1
        time.sleep(0.05)
    time.sleep(0.3)
    linked = len(list(rogue.info.peers_zid()))
    rogue.close()
    after = {k: station.samples[k][n:] for k, n in seen.items()}
    hub_states = [nr.decode_state(p) for p in after[keys.state("nr")] if p != forged_state]
    snapshots = [decode(p, StateSnapshot).values for p in after[keys.ctl("state")]]
    assert linked >= 1 and own_state in after[keys.state("rsp")], "the rogue did not reach the station at all"
    print(f"figures: {forged} forged commands (seq 2**62, the controller's id) and {forged} forged nr states "
          f"with pi-rsp's certificate; hub states seen {len(hub_states)}, controller snapshots {len(snapshots)}, "
          f"commands the rogue received {len(stolen)}, its own rsp states that arrived "
          f"{after[keys.state('rsp')].count(own_state)}")
    taken = [s for s in hub_states if s.mirror is None or s.mirror.seq >= FORGED_SEQ or nr.values(s.mirror)["run_c"]
             or nr.values(s)["run_m"]]
    assert hub_states and not taken, f"the hub took the forged command: {taken[:3]}"
    assert snapshots and not any(v.get("nr.tqr_m") or v.get("nr.fail_m") for v in snapshots), \
        "the controller took the forged state"
    assert forged_state not in after[keys.state("nr")]
    assert stolen == []


def _ask(session: zenoh.Session, station: Station) -> int:
    request = encode(ConsoleRequest(action="ping", origin="test_security"))
    return sum(1 for r in session.get(station.config.keys.ctl("request"), payload=request, timeout=1.0) if r.ok)


@pytest.mark.parametrize(("name", "answered"), [("op", True), ("pi-rsp", False)])
def test_only_an_operator_certificate_may_query_ctl_request(station: Station, name: str, answered: bool) -> None:
    console = station.session(name)
    try:
        _wait(lambda: bool(list(console.info.peers_zid())), SETTLE_S, f"a session with {name}'s certificate linking")
        replies = [_ask(console, station) for _ in range(5)]
    finally:
        console.close()
    print(f"figures: {name}'s certificate, replies to 5 ctl/request queries: {replies}")
    assert replies == [1 if answered else 0] * 5, replies



# --- the parts, without processes ------------------------------------------------------------------

def _secured(tmp: Path, security: str = 'mode = "tls"\noperators = ["op"]') -> StationConfig:
    path = tmp / "hubs.toml"
    path.write_text(_with_security(security), encoding="utf-8")
    return load_station(path)[0]


@pytest.mark.parametrize(("security", "message"), [
    ('mode = "tsl"', "security.mode: unknown mode 'tsl' (expected one of: tls, insecure)"),
    ('operators = ["pi-tool"]', "security.operators: operator 'pi-tool' is already the name of a hub"),
    ('certz = "x"', "security.certz: unknown key"),
])
def test_security_section_errors_name_the_key(tmp_path: Path, security: str, message: str) -> None:
    with pytest.raises(ConfigError) as error:
        _secured(tmp_path, security)
    assert message in str(error.value) and "hubs.toml:" in str(error.value)


def test_certificates_name_holder_and_role_and_stay_private(tmp_path: Path) -> None:
    config = _secured(tmp_path)
    certs = tmp_path / "certs"
    init_ca(certs, config.station.name)
    on_decs = identities_for(config, "decs", None)  # a host: the controller and both hubs on it
    assert [(i.name, i.role) for i in on_decs] == [("decs", "controller"), ("agv", "hub"), ("human", "hub")]
    issued = issue_for_station(certs, config, [*on_decs, identity_of(config, "op")])
    assert role_in_certificate(issued[1].certificate) == ("agv", "hub")
    assert role_in_certificate(issued[3].certificate) == ("op", "operator")
    assert "decs.local" in issued[0].hosts  # where the hubs connect to the controller: its name is checked
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in certs.iterdir()}
    assert set(modes.values()) == {0o600} and stat.S_IMODE(certs.stat().st_mode) == 0o700
    with pytest.raises(SecurityError, match=r"has role hub in hubs\.toml, not operator$"):
        identities_for(config, "pi-tool", "operator")
    with pytest.raises(SecurityError, match="inside the git work tree"):
        init_ca(ROOT / "certs", config.station.name)
    assert not (ROOT / "certs").exists()
    with pytest.raises(SecurityError, match="hubctl certs issue pi-rsp --role hub"):
        tls_files(certs, identity_of(config, "pi-rsp"))


def test_access_control_gives_each_holder_only_its_own_keys(tmp_path: Path) -> None:
    config = _secured(tmp_path)
    acl = access_control(config, config.load_model())
    rules = {r["id"]: r for r in acl["rules"]}
    sends = {p["subjects"][0]: [rules[r] for r in p["rules"]] for p in acl["policies"] if p["id"].endswith("-sends")}
    puts = {s: sorted(k for r in rs if "put" in r["messages"] for k in r["key_exprs"]) for s, rs in sends.items()}
    assert puts["hub-pi-tool"] == ["engine_assembly/hub/pi-tool/selftest", "engine_assembly/res/lift/state",
                                   "engine_assembly/res/nr/state"]
    assert puts["controller-decs"] == ["engine_assembly/ctl/**", "engine_assembly/res/*/cmd"]
    assert puts["operator-op"] == []
    queries = {s: [k for r in rs if "query" in r["messages"] for k in r["key_exprs"]] for s, rs in sends.items()}
    assert "engine_assembly/ctl/request" in queries["operator-op"] and queries["hub-pi-tool"] == []
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    # the hubs, the controller, the operator and the overview page (the viewer role: it may only read)
    assert subjects["controller-decs"] == ["decs"] and len(subjects) == len(config.hubs) + 3
    assert acl["enabled"] and acl["default_permission"] == "deny"


def test_units_and_deploy_ship_and_use_the_hosts_certificate(tmp_path: Path) -> None:
    config = _secured(tmp_path, f'mode = "tls"\noperators = ["op"]\ncerts = "{tmp_path / "certs"}"')
    assert "--certs /opt/statehub/hubs/pi-tool/certs" in hub_unit(config, "pi-tool").text
    assert "--certs /opt/statehub/controller/certs" in controller_unit(config).text
    with pytest.raises(SecurityError, match=r"no .*ca\.crt .*hubctl certs init"):
        hub_cert_files(config, "pi-tool")
    init_ca(tmp_path / "certs", config.station.name)
    issue_for_station(tmp_path / "certs", config, [identity_of(config, "pi-tool")])
    names = [n for n, _ in hub_cert_files(config, "pi-tool")]
    assert names == ["ca.crt", "pi-tool.crt", "pi-tool.key"]
    script = install_unit(Layout(), "r1", "/tmp/stage", "u.service", [], certs=("/opt/statehub/hubs/pi-tool/certs",
                                                                                 names))
    assert "install -m 0600 -o statehub -g statehub /tmp/stage/pi-tool.key /opt/statehub/hubs/pi-tool/certs/" \
           "pi-tool.key" in script
    assert "install -d -m 0700 -o statehub -g statehub /opt/statehub/hubs/pi-tool/certs" in script
