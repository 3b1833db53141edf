"""Issue 12 against real processes over Zenoh on loopback: a rogue peer, a second controller, a restart,
floods of oversized and garbage payloads, and SIGTERM of a running nutrunner hub.

The station is tests/fault_station (controller `--hold`: nothing runs, the commands are steady, so any
change an attack makes shows), its processes started by `harness.Station`; the rogue is the
watcher's own Zenoh session (another peer on the controller's listener) or `tests/bus_peer.py`.
The figures these tests print (`-s`) are the README's (Security and robustness).
"""

from __future__ import annotations

import asyncio
import itertools
import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import pytest

from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import free_port
from common.wire.holder_token import declare_holder
from common.wire.messages import Codec, HubStatus
from controller.station_hold import EXIT_CONFLICT
from tests.fault_station.checks import controller_commands
from tests.fault_station.harness import Station
from tests.fault_station.watcher import Seen
from tests.hub_process import ROOT, HubProcess

pytestmark = pytest.mark.timeout(120)

HUBS_TOML = ROOT / "hubs.toml"
BUS_PEER = Path(__file__).with_name("bus_peer.py")
RSS_LIMIT_KB = 60 * 1024


@pytest.fixture
def station(tmp_path: Path) -> Iterator[Station]:
    with Station(tmp_path, hold=True) as s:
        s.start()
        s.wait_for(lambda: all((m := s.watch.state(r).mirror) is not None and m.controller.startswith("ctl-")
                               for r in ("nr", "ur")), 10, "every hub applies the controller's commands")
        # The hubs can apply a first command sent before the watcher's subscription reached the
        # controller (a loaded machine): the tests replay one the watcher recorded, re-sent at the command rate.
        s.wait_for(lambda: all(controller_commands(s, r) for r in ("nr", "ur")), 10,
                   "the watcher records the controller's commands")
        yield s


def holder_command(station: Station, resource: str) -> Any:
    # Any: the command struct is generated from the resource's model; its fields have no static type.
    return controller_commands(station, resource)[-1].message


def replayed(station: Station, resource: str, **changes: object) -> bytes:
    codec = station.watch.codecs[resource]
    return codec.encode_command(msgspec.structs.replace(holder_command(station, resource), **changes))


def states_since(station: Station, resource: str, since: float) -> list[Seen]:
    return [s for s in station.watch.states(resource) if s.at >= since]


def test_a_forged_huge_seq_changes_no_output_and_holds_no_genuine_command_back(station: Station) -> None:
    genuine = holder_command(station, "nr")
    assert genuine.epoch >= 1 and genuine.run_c is False
    forged_at = time.monotonic()
    # In the controller's name, with an epoch it does not hold (the next one, none): run the tool.
    for epoch in (genuine.epoch + 1, 0):
        station.watch.publish(station.keys.cmd("nr"), replayed(station, "nr", seq=2**62, epoch=epoch, run_c=True))
    time.sleep(1.0)
    # A replay of the genuine command with seq 2**62 (its id and epoch are public: only the links'
    # access control, not the hub, can tell it apart). The controller sees its own name mirrored with a
    # seq it never sent and takes a new epoch: its next commands are applied again at once.
    station.watch.publish(station.keys.cmd("nr"), replayed(station, "nr", seq=2**62))
    renewed = station.wait_for(
        lambda: next((s.message for s in states_since(station, "nr", forged_at) if s.message.mirror is not None
                      and s.message.mirror.epoch > genuine.epoch), None), 5,
        "the hub applies the controller's commands in its new epoch")
    time.sleep(1.5)  # longer than the command timeout: a held-back controller would show as a safe state

    after = states_since(station, "nr", forged_at)
    assert renewed.mirror.controller == genuine.controller and renewed.mirror.seq < 2**62
    assert all(s.message.run_m is False for s in after), "the forgery ran the tool"
    assert not [s for s in after if s.message.status in (HubStatus.SAFE_STATE, HubStatus.REJECTED)]
    mirrors = {(s.message.mirror.controller, s.message.mirror.epoch, s.message.mirror.run_c) for s in after}
    assert mirrors <= {(genuine.controller, e, False) for e in (genuine.epoch, genuine.epoch + 1)}
    last = after[-1].message.mirror
    assert last.epoch == genuine.epoch + 1 and last.seq < 2**62 and last.time > renewed.mirror.time
    assert station.all_healthy() and not station.dead()
    log = station.processes["controller"].tail(10**6)
    assert "a forged command" in log and f"holding the station in epoch {genuine.epoch + 1}" in log
    assert "not the station's holder" in station.processes["pi-tool"].tail(10**6)


def test_a_second_controller_refuses_to_start_naming_the_first_and_outputs_never_alternate(
        station: Station, tmp_path: Path) -> None:
    first = station.watch.status()
    assert first is not None
    # The same station, the second controller linked to the first (its own listener, the first's as peer).
    text = station.config_path.read_text().replace(
        "[controller]\n", f'[controller]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
                          f'connect = ["tcp/127.0.0.1:{station.port}"]\n', 1)
    second_config = tmp_path / "second.toml"
    second_config.write_text(text)
    began = time.monotonic()
    second = subprocess.run([sys.executable, "-m", "controller", "--config", str(second_config), "--db",
                             str(tmp_path / "second.sqlite")], cwd=ROOT, capture_output=True, text=True, timeout=60,
                            env=station._env)
    print(f"\nsecond controller refused in {time.monotonic() - began:.2f} s: {second.stderr.strip().splitlines()[-1]}")
    assert second.returncode == EXIT_CONFLICT, second.stderr
    pid = station.processes["controller"].pid
    assert re.search(rf"held by controller {re.escape(first.controller)} \(epoch 1, host \S+, pid {pid}\)",
                     second.stderr), second.stderr
    # Nothing of it reached a hub: every mirror since is the first controller's.
    for resource in ("nr", "ur"):
        assert {s.message.mirror.controller for s in states_since(station, resource, began)} == {first.controller}
    # and the first controller goes on with every resource healthy (a snapshot can catch a resource stale for a
    # moment while the second's start-up starved a loaded machine: one fresh-clone suite in several did)
    station.wait_for(station.all_healthy, 10.0, "every resource healthy under the first controller")
    assert not station.dead()


def test_a_restarted_controller_is_followed_at_once_in_its_new_epoch_and_the_old_refused(station: Station) -> None:
    old = holder_command(station, "nr")
    station.kill("controller")
    restarted_at = time.monotonic()
    station.start_controller(fresh=False)
    new_command = station.wait_for(
        lambda: next((c for c in station.watch.commands("nr") if c.at > restarted_at), None), 30,
        "the restarted controller commands")
    taken = station.wait_for(
        lambda: next((s for s in states_since(station, "nr", restarted_at) if s.message.mirror is not None
                      and s.message.mirror.controller == new_command.message.controller), None),
        5, "the hub applies the restarted controller's commands")
    delay_ms = 1000 * (taken.message.time - new_command.message.time)
    print(f"\nrestarted controller's first command mirrored {delay_ms:.0f} ms after it was sent "
          f"(the hub's publication time minus the controller's send time)")
    assert new_command.message.epoch == old.epoch + 1 and new_command.message.controller != old.controller
    # A late command of the old epoch (replayed by a rogue): refused.
    late_at = time.monotonic()
    station.watch.publish(station.keys.cmd("nr"), station.watch.codecs["nr"].encode_command(
        msgspec.structs.replace(old, seq=old.seq + 1, run_c=True)))
    time.sleep(0.5)
    assert all(s.message.mirror.controller == new_command.message.controller and s.message.run_m is False
               for s in states_since(station, "nr", late_at))
    station.wait_for(station.all_healthy, 10, "every resource healthy under the restarted controller")


# --- floods on a hub's command key --------------------------------------------------------------

def rss_kb(pid: int, field: str = "VmRSS") -> int:
    match = re.search(rf"^{field}:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text(), re.MULTILINE)
    assert match, f"no {field} for pid {pid}"
    return int(match.group(1))


def max_gap_s(times: list[float]) -> float:
    return max((b - a for a, b in itertools.pairwise(times)), default=float("inf"))


async def flood(port: int, station: str, key: str, count: int, size: int, log: Path) -> None:
    """`bus_peer.py flood` as a rogue process; returns once it has put everything."""
    with log.open("ab") as err:
        peer = await asyncio.create_subprocess_exec(
            sys.executable, str(BUS_PEER), "flood", f"tcp/127.0.0.1:{port}", station, key, str(count), str(size),
            stdout=asyncio.subprocess.PIPE, stderr=err, cwd=ROOT)
    try:
        assert peer.stdout is not None
        for expected in (b"ready", b"sent"):
            line = await asyncio.wait_for(peer.stdout.readline(), 60)
            assert line.strip() == expected, f"flood peer said {line!r}; log: {log.read_text()[-2000:]}"
    finally:
        peer.kill()
        await peer.wait()


async def test_oversized_and_garbage_floods_neither_stall_nor_bloat_the_hub(tmp_path: Path) -> None:
    config, model = load_station(HUBS_TOML)
    keys, codec = config.keys, Codec(model.resource_by_name["nr"])
    port = free_port()
    async with ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"])) as bus:
        declare_holder(bus, keys, "test-controller")
        states = bus.subscribe(keys.state("nr"), coalesce=False, maxlen=None)
        alive = bus.watch_liveliness(keys.alive("pi-tool"))
        hub = HubProcess(HUBS_TOML, "pi-tool", port, tmp_path / "pi-tool.log").start()
        try:
            assert (await asyncio.wait_for(alive.get(), 30)).alive
            assert hub.process is not None
            command = codec.encode_command(codec.command({"run_c": False}, seq=1, controller="test-controller"))

            async def command_at_10_hz() -> None:
                while True:
                    bus.publish(keys.cmd("nr"), command)
                    await asyncio.sleep(0.1)

            sender = asyncio.create_task(command_at_10_hz())
            await asyncio.sleep(0.5)
            states.take_all()
            await asyncio.sleep(2.0)
            quiet = [codec.decode_state(s.payload).time for s in states.take_all()]
            baseline_kb = rss_kb(hub.process.pid)
            await flood(port, config.station.name, keys.cmd("nr"), 2, 100_000_000, tmp_path / "flood.log")
            await flood(port, config.station.name, keys.cmd("nr"), 10_000, 200, tmp_path / "flood.log")
            await asyncio.sleep(0.5)
            sender.cancel()
            peak_kb = rss_kb(hub.process.pid, "VmHWM")
            during = [codec.decode_state(s.payload) for s in states.take_all()]
            assert hub.alive(), hub.log.read_text()[-3000:]
        finally:
            hub.stop()
    # The hub's own publication times: its loop, not ours. On a loaded machine a process may wait for a
    # core whatever it does: the gap is bounded above what the same hub showed just before, unflooded.
    gap, quiet_gap = max_gap_s([s.time for s in during]), max_gap_s(quiet)
    print(f"\nhub under floods: {len(during)} states, max publish gap {1000 * gap:.1f} ms (unflooded "
          f"{1000 * quiet_gap:.1f} ms); RSS {baseline_kb / 1024:.1f} MB before, peak {peak_kb / 1024:.1f} MB")
    assert len(during) > 50 and gap < 0.1 + quiet_gap
    assert peak_kb < RSS_LIMIT_KB
    assert all(s.mirror is not None and s.mirror.controller == "test-controller" and codec.values(s)["run_m"] is False
               for s in during)
    text = hub.log.read_text()
    # 10,000 garbage payloads: a line for the first, then one per interval with the count.
    assert 1 <= text.count("dropped malformed command") < 10, text[-3000:]


# --- SIGTERM of a running nutrunner hub ------------------------------------------------------------

async def test_sigterm_of_a_running_nutrunner_hub_leaves_the_simulated_output_off(tmp_path: Path) -> None:
    config, model = load_station(HUBS_TOML)
    keys, codec = config.keys, Codec(model.resource_by_name["nr"])
    trace = tmp_path / "nr-run-output.trace"
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"nr": {"sim_trace": str(trace), "sim_tighten": 60.0}}))  # stays running
    port = free_port()
    async with ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"])) as bus:
        declare_holder(bus, keys, "test-controller")
        states = bus.subscribe(keys.state("nr"), coalesce=False, maxlen=None)
        hub = HubProcess(HUBS_TOML, "pi-tool", port, tmp_path / "pi-tool.log", "--mode", "sim",
                         "--params-file", str(params)).start()
        try:
            command = codec.encode_command(codec.command({"run_c": True}, seq=1, controller="test-controller"))
            deadline = time.monotonic() + 30
            running = False
            while not running and time.monotonic() < deadline:
                bus.publish(keys.cmd("nr"), command)
                await asyncio.sleep(0.1)
                running = any(codec.values(codec.decode_state(s.payload))["run_m"] for s in states.take_all())
            assert running, hub.log.read_text()[-3000:]
            assert trace.read_text().split()[-1] == "1"  # the simulated run output is on
            assert hub.process is not None
            hub.process.send_signal(signal.SIGTERM)  # while the tool runs and commands keep it on
            exit_code = await asyncio.to_thread(hub.process.wait, 10)
        finally:
            hub.stop()
    levels = [line.split()[1] for line in trace.read_text().splitlines()]
    assert exit_code == 0 and levels[-1] == "0", (levels, hub.log.read_text()[-3000:])
    assert "every output in its safe state on exit" in hub.log.read_text()
