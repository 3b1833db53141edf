"""Line benchmark: a line of stations over Zenoh routers, real processes on loopback.

    python tests/bench/bench_line.py [--round-trips N] [--products N]

(a) command -> mirror through a real hub process (`python -m hubs`, the line station's emulated nutrunner):
    this process plays the controller, publishes a command and times the first state that mirrors it;
    median and p99 in peer mode (the hub links to this process), through one router (both are clients of it)
    and through two (this process a client of r1, the hub of r2).
(b) a 3-station line (tests/line_station/) of N products run by `deploy.line.up.run_line`, insecure:
    * the routers' CPU: each router process's CPU seconds over the run (from /proc), as a share of one core;
    * the overview's bytes per second: every station's `ctl/status` as a client of r1 receives it (what the
      overview reads);
    * the line's engines per hour (products leaving the last station, from the first to the last, on the
      line controller's file) against what the slowest station's median cycle would allow (3600 / cycle).

The machine's load matters: run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from common.bus.zenoh_bus import ZenohBus  # noqa: E402
from common.bus.zenoh_config import zenoh_config  # noqa: E402
from common.config.hubs_toml import load_config, load_station  # noqa: E402
from common.line.config import load_line  # noqa: E402
from common.plumbing.lifecycle import free_port  # noqa: E402
from common.wire.holder_token import declare_holder  # noqa: E402
from common.wire.messages import Codec  # noqa: E402
from deploy.line.store import VisitState  # noqa: E402
from deploy.line.up import LineOptions, run_line  # noqa: E402
from tests.bench.bench_station import mirrored_at  # noqa: E402
from tests.line_station.site import write_line  # noqa: E402

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(len(ordered) * q))]


def stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def cpu_seconds(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def processes_with(text: str) -> list[int]:
    """The pids whose command line holds `text` (this benchmark's own children, by their unique paths)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


# --- (a) command -> mirror ----------------------------------------------------------------------------

async def round_trips(directory: Path, how: str, count: int) -> list[float]:
    """Command -> mirror in ms, `how`: "peer", "1 router" or "2 routers"."""
    line = load_line(write_line(directory, 2))
    station = line.stations["s2" if how == "2 routers" else "s1"]  # s2 is r2's, s1 r1's
    config, model = load_station(station.config)
    keys = config.keys
    hub_name = next(h for h in config.hubs if "pi-tool" in h)
    codec = Codec(model.resource_by_name["nr"])
    started: list[subprocess.Popen[bytes]] = []
    log = (directory / f"{how.replace(' ', '-')}.log").open("wb")

    def spawn(*argv: str) -> None:
        started.append(subprocess.Popen([sys.executable, *argv], cwd=ROOT, env=ENV, stdout=log,
                                        stderr=subprocess.STDOUT))

    if how == "peer":
        port = free_port()
        zconfig = zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"], lease_ms=1000)
        hub_args = ["--loopback-port", str(port)]
    else:
        for router in line.routers:
            spawn("-m", "deploy.router", "--config", str(line.path), "--name", router)
        zconfig = zenoh_config("client", connect=line.router_endpoints("r1"), lease_ms=1000)
        hub_args = []
    try:
        async with ZenohBus(zconfig) as bus:
            states = bus.subscribe(keys.state("nr"), coalesce=False, maxlen=None)
            alive = bus.watch_liveliness(keys.alive(hub_name))
            declare_holder(bus, keys, "bench")
            spawn("-m", "hubs", hub_name, "--config", str(station.config), *hub_args)
            await asyncio.wait_for(alive.get(), 60)
            seq = 0

            async def mirrored(wanted: int, timeout: float = 2.0) -> float:
                return await mirrored_at(states, codec, wanted, timeout)

            seq = 1
            first = codec.encode_command(codec.command({"run_c": False}, seq=seq, controller="bench"))
            for _ in range(200):  # until the hub applies the holder's commands
                bus.publish(keys.cmd("nr"), first)
                try:
                    await mirrored(seq, 0.1)
                    break
                except TimeoutError:
                    continue
            rtts = []
            for i in range(count):
                seq += 1
                payload = codec.encode_command(codec.command({"run_c": i % 2 == 0}, seq=seq, controller="bench"))
                states.take_all()
                began = time.perf_counter()
                bus.publish(keys.cmd("nr"), payload)
                rtts.append((await mirrored(seq) - began) * 1000)
                await asyncio.sleep(0.005 + (i % 7) * 0.002)  # decorrelate from the hub's period
    finally:
        for process in reversed(started):
            stop(process)
        log.close()
    return rtts


# --- (b) a line run -------------------------------------------------------------------------------------

class Sampler:
    """CPU seconds of the processes `find` returns, sampled every second (a process's last sample counts)."""

    def __init__(self, find: Callable[[], list[int]]) -> None:
        self.find = find
        self.first: dict[int, float] = {}
        self.last: dict[int, float] = {}

    async def run(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            for pid in self.find():
                cpu = cpu_seconds(pid)
                if cpu is not None:
                    self.first.setdefault(pid, cpu)
                    self.last[pid] = cpu
            try:
                async with asyncio.timeout(1.0):
                    await stop.wait()
            except TimeoutError:
                pass

    def seconds(self) -> float:
        return sum(self.last[pid] - self.first[pid] for pid in self.last)


async def status_bytes(line_path: Path, stop: asyncio.Event, counted: list[int]) -> None:
    line = load_line(line_path)
    keys = [load_config(s.config).keys for s in line.stations.values()]
    config = zenoh_config("client", connect=line.router_endpoints("r1"), lease_ms=1000)
    async with ZenohBus(config) as bus:
        subscriptions = [bus.subscribe(k.ctl("status"), coalesce=False, maxlen=None) for k in keys]
        while not stop.is_set():
            await asyncio.sleep(0.5)
            for subscription in subscriptions:
                counted.extend(len(sample.payload) for sample in subscription.take_all())


async def line_figures(directory: Path, products: int) -> None:
    line_path = write_line(directory, 3)
    stop = asyncio.Event()
    routers = Sampler(lambda: processes_with(f"deploy.router --config {line_path}"))
    counted: list[int] = []
    sampling = [asyncio.create_task(routers.run(stop)), asyncio.create_task(status_bytes(line_path, stop, counted))]
    began = time.monotonic()
    result = await run_line(LineOptions(config=str(line_path), products=products, run_dir=directory / "run",
                                        overview_every_s=3600.0, record=False), lambda _line: None)
    elapsed = time.monotonic() - began
    stop.set()
    await asyncio.gather(*sampling, return_exceptions=True)
    line = load_line(line_path)
    db = sqlite3.connect(line.db)
    rows = db.execute("SELECT station, started_at, finished_at FROM visits WHERE state=?",
                      (VisitState.DONE.value,)).fetchall()
    cycles: dict[str, list[float]] = {}
    for station, started_at, finished_at in rows:
        if started_at is not None and finished_at is not None:
            cycles.setdefault(station, []).append(finished_at - started_at)
    last = line.route[-1]
    leaving = sorted(f for (f,) in db.execute("SELECT finished_at FROM visits WHERE station=? AND state=?",
                                               (last, VisitState.DONE.value)))
    db.close()
    print(f"(b) a line of {len(line.route)} stations over {len(line.routers)} routers, {products} products: "
          f"{'finished' if result.finished else 'NOT finished'} in {elapsed:.1f} s")
    print(f"    routers' CPU: {routers.seconds():.2f} s over {elapsed:.1f} s = "
          f"{100 * routers.seconds() / elapsed:.1f} % of one core (both routers)")
    print(f"    overview: {sum(counted) / elapsed:,.0f} bytes/s ({len(counted)} statuses of {len(line.route)} "
          f"stations, {statistics.mean(counted) if counted else 0:.0f} bytes on average)")
    medians = {s: statistics.median(c) for s, c in cycles.items()}
    for station in line.route:
        print(f"    {station}: cycle median {medians.get(station, float('nan')):.2f} s over "
              f"{len(cycles.get(station, []))} products")
    if len(leaving) >= 2 and medians:
        per_hour = (len(leaving) - 1) / (leaving[-1] - leaving[0]) * 3600
        slowest = max(medians.values())
        print(f"    line: {per_hour:.0f} engines per hour (products leaving {last}, first to last); the slowest "
              f"station's median cycle {slowest:.2f} s allows {3600 / slowest:.0f}: {per_hour * slowest / 36:.0f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--round-trips", type=int, default=300)
    parser.add_argument("--products", type=int, default=8)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_line_") as tmp:
        directory = Path(tmp)
        print("(a) command -> mirror through a hub process (ms):")
        for how in ("peer", "1 router", "2 routers"):
            where = directory / how.replace(" ", "-")
            where.mkdir()
            rtts = asyncio.run(round_trips(where, how, args.round_trips))
            print(f"    {how:<10} median {statistics.median(rtts):6.2f}  p99 {percentile(rtts, 0.99):6.2f}  "
                  f"max {max(rtts):6.2f}  ({len(rtts)} round trips)")
        where = directory / "line"
        where.mkdir()
        asyncio.run(line_figures(where, args.products))


if __name__ == "__main__":
    main()
