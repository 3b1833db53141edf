"""Station benchmark: the running station's figures, with real processes over Zenoh on loopback.

    python tests/bench/bench_station.py [--quick] [--max-resources N]

(a) command -> mirror round trip through a real hub process (`python -m hubs`, one emulated
    nutrunner, 50 Hz): this process plays the controller, publishes a command and times
    the first state that mirrors it. Median and p99 (target p99 < 5 ms).
(b) controller capacity: a real controller process (`python -m controller`) with a synthetic
    model of N nutrunners, served by load-generator processes (bench_station_load.py,
    one per 250 resources, each a hub of the station) that publish each resource's state
    at 50 Hz (spread over the period, as independent hubs would), mirror the commands they
    receive and hold their hub's liveliness token. N is stepped up; a step passes while the controller's tick median
    stays < 5 ms, no ingested state is older than 3 periods (p99 of publication ->
    ingestion), it ingests >= 95 % of what is offered, and every resource stays healthy.
    The controller measures itself (`StatusMessage.loop`). Target: >= 500 resources
    (25,000 states/s).
(c) one hub with one resource at 50 Hz, commanded at 10 Hz as the controller does: its
    share of one core and its RSS, from /proc (targets < 3 %, < 60 MB).
(d) the baseline: raw zenoh-python and our asyncio Bus, ping-pong between two processes
    (tests/bench/bench_bus.py).
(e) what recording the run costs (common/recording): (b) at 500 resources with the controller
    recording and with `--no-record`, alternately; its tick median and its ingest capacity, i.e. the
    states it ingests per second of its CPU (one core's worth is what it could ingest at most); the
    recording's writer is a process of its own, whose CPU is printed apart. Then the same in one
    process without Zenoh (bench_recording.py), steadier on a busy machine,
    with values that never change and with values that change in every state (the worst case).
    Target: recording costs < 5 % of the ingest capacity. `--recording-only` runs just this.

The machine's load matters: run it on an otherwise idle machine. `--quick` (< 60 s) uses
fewer round trips, shorter windows and N up to 1000.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from common.bus.inbox import Subscription  # noqa: E402
from common.bus.protocol import Sample  # noqa: E402
from common.bus.zenoh_bus import ZenohBus  # noqa: E402
from common.bus.zenoh_config import zenoh_config  # noqa: E402
from common.plumbing.lifecycle import free_port  # noqa: E402
from common.wire.holder_token import declare_holder  # noqa: E402
from common.wire.keys import station_keys  # noqa: E402
from common.wire.messages import Codec  # noqa: E402
from controller.recording.writer import RECORDING_DIR_ENV  # noqa: E402
from tests.bench.bench_station_load import HUB_RATE_HZ, RESOURCES_ENV, generator_slices, write_station  # noqa: E402

TICK_MEDIAN_LIMIT_MS = 5.0
AGE_LIMIT_MS = 3 * 1000.0 / HUB_RATE_HZ
INGEST_SHARE = 0.95
FAULT_STATION = ROOT / "tests" / "fault_station" / "hubs.toml"
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(len(ordered) * q))]


def stop(process: subprocess.Popen[bytes] | None) -> None:
    if process is None or process.poll() is not None:
        return
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(5)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)


# --- (b) one step: a controller and load generators with N resources ---------------------------------


async def mirrored_at(states: Subscription[Sample], codec: Codec, wanted: int, timeout: float = 2.0) -> float:
    """When (perf_counter) the hub's state first mirrors command `wanted`; TimeoutError after `timeout` s."""
    deadline = time.monotonic() + timeout
    while True:
        sample = await asyncio.wait_for(states.get(), max(0.001, deadline - time.monotonic()))
        state = codec.decode_state(sample.payload)
        if state.mirror is not None and state.mirror.seq == wanted:
            return time.perf_counter()


@dataclass
class Step:
    resources: int
    offered: float = 0.0  # states/s the generators sent
    ingested: float = 0.0  # states/s the controller ingested
    dropped: int = 0
    tick_median_ms: float = 0.0
    tick_p99_ms: float = 0.0
    ticks_per_s: float = 0.0
    age_median_ms: float = 0.0
    age_p99_ms: float = 0.0
    age_max_ms: float = 0.0
    unhealthy: int = 0
    controller_cpu: float = 0.0  # share of one core
    writer_cpu: float = 0.0  # of its recording's writer process (controller/recording/writer.py), apart
    problem: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.problem and self.tick_median_ms < TICK_MEDIAN_LIMIT_MS and self.age_p99_ms <= AGE_LIMIT_MS \
            and self.ingested >= INGEST_SHARE * self.resources * HUB_RATE_HZ and self.unhealthy == 0

    def row(self) -> str:
        verdict = "pass" if self.passed else f"FAIL{': ' + self.problem if self.problem else ''}"
        return (f"{self.resources:>6} {self.resources * HUB_RATE_HZ:>9,.0f} {self.offered:>9,.0f} "
                f"{self.ingested:>9,.0f} {self.dropped:>8} {self.tick_median_ms:>7.2f} {self.tick_p99_ms:>7.2f} "
                f"{self.ticks_per_s:>6.0f} "
                f"{self.age_median_ms:>7.1f} {self.age_p99_ms:>7.1f} {self.age_max_ms:>7.1f} {self.unhealthy:>5} "
                f"{100 * self.controller_cpu:>5.0f}%  {verdict}")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def recording_writer(controller: int) -> int | None:
    """The pid of the controller's recording writer process (its child running writer_process), if any."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == controller and \
                    b"writer_process" in stat.with_name("cmdline").read_bytes():
                return int(stat.parent.name)
        except (OSError, ValueError, IndexError):
            continue
    return None


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


async def capacity_step(directory: Path, resources: int, warmup: float, window: float, *,
                        record: bool = True) -> Step:
    from common.wire.ctl import StatusMessage
    from common.wire.messages import MessageError, decode

    step = Step(resources)
    station = f"bench_{os.getpid()}_{uuid.uuid4().hex[:6]}"
    config = write_station(directory, station, resources)
    port = free_port()
    keys = station_keys(station)
    env = {**ENV, RESOURCES_ENV: str(resources), RECORDING_DIR_ENV: str(directory / "runs")}
    log = (directory / f"controller_{resources}.log").open("wb")
    controller = subprocess.Popen(
        [sys.executable, "-m", "controller", "--config", str(config), "--loopback-port", str(port),
         "--db", str(directory / f"bench_{resources}.sqlite"), "--fresh", *([] if record else ["--no-record"])],
        cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    gens: list[subprocess.Popen[bytes]] = []
    try:
        async with ZenohBus(zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"])) as bus:
            statuses = bus.subscribe(keys.ctl("status"), coalesce=False, maxlen=None)
            for k, served in enumerate(generator_slices(resources)):
                gens.append(subprocess.Popen(
                    [sys.executable, str(HERE / "bench_station_load.py"), f"tcp/127.0.0.1:{port}", station, f"gen{k}",
                     str(resources), str(served.start), str(served.stop)],
                    cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE))
            for gen in gens:
                assert gen.stdout is not None
                line = await asyncio.to_thread(gen.stdout.readline)
                if line.strip() != b"ready":
                    step.problem = f"generator did not start: {line!r}"
                    return step

            async def next_status(deadline: float) -> StatusMessage | None:
                while time.monotonic() < deadline:
                    try:
                        sample = await asyncio.wait_for(statuses.get(), max(0.01, deadline - time.monotonic()))
                    except TimeoutError:
                        return None
                    try:
                        return decode(sample.payload, StatusMessage)
                    except MessageError:
                        continue
                return None

            # Up, and every resource healthy, then warm up.
            deadline = time.monotonic() + 30 + resources / 50
            status = None
            while time.monotonic() < deadline:
                status = await next_status(deadline)
                if status is not None and status.health and all(h.healthy for h in status.health):
                    break
            else:
                unhealthy = [h for h in status.health if not h.healthy] if status else []
                step.problem = (f"not all healthy ({len(unhealthy)} not, e.g. {unhealthy[0].reason})" if unhealthy
                                else "no status")
                return step
            await asyncio.sleep(warmup)
            statuses.take_all()
            writer = recording_writer(controller.pid)
            writer0 = cpu_seconds(writer) if writer is not None else 0.0
            cpu0, t0 = cpu_seconds(controller.pid), time.monotonic()
            windows = []
            last = None
            end = time.monotonic() + window
            while time.monotonic() < end:
                status = await next_status(end)
                if status is None:
                    break
                last = status
                if status.loop is not None and status.loop.window_s > 0:
                    windows.append(status.loop)
            step.controller_cpu = (cpu_seconds(controller.pid) - cpu0) / (time.monotonic() - t0)
            if writer is not None:
                step.writer_cpu = (cpu_seconds(writer) - writer0) / (time.monotonic() - t0)
            if not windows or last is None:
                step.problem = "no loop statistics in the controller's status (StatusMessage.loop)"
                return step
            seconds = sum(w.window_s for w in windows)
            step.ingested = sum(w.states for w in windows) / seconds
            step.dropped = sum(w.states_dropped for w in windows)
            step.ticks_per_s = sum(w.ticks for w in windows) / seconds
            # Median of the windows' medians (each window is ~0.25 s), worst p99 and max.
            step.tick_median_ms = statistics.median(w.tick_ms_median for w in windows if w.ticks)
            step.tick_p99_ms = max(w.tick_ms_p99 for w in windows)
            step.age_median_ms = statistics.median(w.state_age_ms_median for w in windows if w.states)
            step.age_p99_ms = max(w.state_age_ms_p99 for w in windows)
            step.age_max_ms = max(w.state_age_ms_max for w in windows)
            step.unhealthy = sum(1 for h in last.health if not h.healthy)
    finally:
        for gen in gens:  # stdin closed: each one stops and reports
            if gen.poll() is None and gen.stdin is not None:
                gen.stdin.close()
        late = 0
        for gen in gens:
            if gen.poll() is not None and gen.returncode != 0:
                continue
            assert gen.stdout is not None
            try:
                out = gen.stdout.read().decode().strip().splitlines()
                gen.wait(10)
                report = json.loads(out[-1]) if out else {}
                if report:
                    step.offered += report["sent"] / report["elapsed"]
                    late += report["late_periods"]
            except (subprocess.TimeoutExpired, ValueError):
                gen.kill()
        if late:
            step.notes.append(f"the generators fell behind {late} times")
        stop(controller)
        log.close()
    if step.offered and step.offered < 0.95 * resources * HUB_RATE_HZ:
        step.notes.append(f"the generators offered only {step.offered:,.0f} states/s: they are the bottleneck")
    return step


# --- (a) + (c) the round trip through a real hub, and the hub's footprint -----------------------------

@dataclass
class HubFigures:
    rtts_ms: list[float]
    cpu_share: float
    rss_mb: float
    measured_s: float


async def hub_figures(directory: Path, round_trips: int, footprint_s: float) -> HubFigures:
    from common.config.hubs_toml import load_station

    text = FAULT_STATION.read_text().replace('name = "fault_station"', f'name = "bench_hub_{os.getpid()}"', 1)
    config_path = directory / "hub.toml"
    config_path.write_text(text)
    config, model = load_station(config_path)
    keys = config.keys
    codec = Codec(model.resource_by_name["nr"])
    port = free_port()
    log = (directory / "hub.log").open("wb")
    async with ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"])) as bus:
        states = bus.subscribe(keys.state("nr"), coalesce=False, maxlen=None)
        alive = bus.watch_liveliness(keys.alive("pi-tool"))
        declare_holder(bus, keys, "bench")  # the hub applies the holder's commands only
        hub = subprocess.Popen([sys.executable, "-m", "hubs", "pi-tool", "--config", str(config_path),
                                "--loopback-port", str(port)], cwd=ROOT, env=ENV, stdout=log, stderr=subprocess.STDOUT)
        try:
            await asyncio.wait_for(alive.get(), 30)
            seq = 0

            def command(run_c: bool) -> bytes:
                return codec.encode_command(codec.command({"run_c": run_c}, seq=seq, controller="bench"))

            async def mirrored(wanted: int, timeout: float = 2.0) -> float:
                return await mirrored_at(states, codec, wanted, timeout)

            # (c) the footprint, commanded as a controller does at rest: the same command re-sent at 10 Hz.
            seq = 1
            payload = command(False)
            for _ in range(100):  # re-sent until applied, as the controller does (the hub may still be starting)
                bus.publish(keys.cmd("nr"), payload)
                try:
                    await mirrored(seq, 0.1)
                    break
                except TimeoutError:
                    continue
            await asyncio.sleep(1.0)
            cpu0, t0 = cpu_seconds(hub.pid), time.monotonic()
            while time.monotonic() - t0 < footprint_s:
                bus.publish(keys.cmd("nr"), payload)
                await asyncio.sleep(0.1)
                states.take_all()
            measured = time.monotonic() - t0
            cpu_share = (cpu_seconds(hub.pid) - cpu0) / measured
            rss = rss_mb(hub.pid)

            # (a) command -> mirror: each new command (run_c toggles, so the device works too).
            rtts = []
            for i in range(round_trips):
                seq += 1
                payload = command(i % 2 == 0)
                states.take_all()
                began = time.perf_counter()
                bus.publish(keys.cmd("nr"), payload)
                rtts.append((await mirrored(seq) - began) * 1000)
                await asyncio.sleep(0.005 + (i % 7) * 0.002)  # decorrelate from the hub's 20 ms period
        finally:
            stop(hub)
            log.close()
    return HubFigures(rtts, cpu_share, rss, measured)


# --- (e) recording on and off ----------------------------------------------------------------------------

RECORDING_RESOURCES = 500
RECORDING_COST_LIMIT = 0.05


def recording_cost(directory: Path, rounds: int, warmup: float, window: float) -> None:
    """(b) at 500 resources, recording off and on in turn (the machine's load drifts: pairs, not blocks)."""
    steps: dict[bool, list[Step]] = {False: [], True: []}
    for _ in range(rounds):
        for record in (False, True):
            step = asyncio.run(capacity_step(directory, RECORDING_RESOURCES, warmup, window, record=record))
            steps[record].append(step)
            print(f"    recording {'on ' if record else 'off'}: tick median {step.tick_median_ms:.2f} ms, ingested "
                  f"{step.ingested:,.0f}/s, controller cpu {100 * step.controller_cpu:.0f} %"
                  + (f", its recording's writer process {100 * step.writer_cpu:.1f} %" if record else "")
                  + (f" {step.problem}" if step.problem else ""), flush=True)

    def capacity(step: Step) -> float:  # states ingested per CPU second of the controller
        return step.ingested / step.controller_cpu if step.controller_cpu else 0.0

    figures = {record: (statistics.median(s.tick_median_ms for s in done), statistics.median(map(capacity, done)))
               for record, done in steps.items()}
    (tick_off, capacity_off), (tick_on, capacity_on) = figures[False], figures[True]
    cost = 1 - capacity_on / capacity_off if capacity_off else float("nan")
    print()
    print(f"(e) recording at {RECORDING_RESOURCES} resources x {HUB_RATE_HZ:.0f} Hz, median of {rounds} rounds:")
    print(f"    {'':<14} {'tick median':>12} {'ingest capacity':>24}")
    print(f"    {'recording off':<14} {tick_off:>9.2f} ms {capacity_off:>14,.0f} states/cpu-s")
    print(f"    {'recording on':<14} {tick_on:>9.2f} ms {capacity_on:>14,.0f} states/cpu-s")
    print(f"    on/off: tick x{tick_on / tick_off if tick_off else float('nan'):.3f}, ingest capacity "
          f"x{capacity_on / capacity_off if capacity_off else float('nan'):.3f}: recording costs {100 * cost:.1f} % "
          f"(target < {100 * RECORDING_COST_LIMIT:.0f} %) {'ok' if cost < RECORDING_COST_LIMIT else 'MISSED'}")
    sizes = [p.stat().st_size for p in (directory / "runs").glob("*.sqlite")]
    if sizes:
        per_s = statistics.median(sizes) / (window + warmup)
        print(f"    recording size: about {per_s / 1024:,.0f} kB per second of run (states are recorded when they "
              f"change; the load generators' values hardly do)")
    print("(e) the same in one process, states handed to the controller's ingestion (bench_recording.py):", flush=True)
    from tests.bench import bench_recording

    bench_recording.report(RECORDING_RESOURCES, window, rounds, RECORDING_COST_LIMIT)


# --- the report ----------------------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="a smoke run in under a minute")
    parser.add_argument("--max-resources", type=int, help="step the capacity up to this many resources")
    parser.add_argument("--recording-only", action="store_true", help="only (e): recording on and off")
    parser.add_argument("--rounds", type=int, default=3, help="(e): off/on pairs (default 3)")
    args = parser.parse_args()
    if args.recording_only:
        with tempfile.TemporaryDirectory(prefix="bench_station_") as tmp:
            print("(e) controller at 500 resources, recording off and on ...", flush=True)
            recording_cost(Path(tmp), args.rounds, *((1.0, 2.0) if args.quick else (2.0, 5.0)))
        return

    from tests.bench import bench_bus

    started = time.perf_counter()
    quick = args.quick
    round_trips, footprint_s = (300, 3.0) if quick else (2000, 10.0)
    steps = [100, 250, 500, 1000] if quick else [100, 200, 300, 400, 500, 750, 1000, 1500, 2000, 3000]
    if args.max_resources:
        steps = [n for n in steps if n < args.max_resources] + [args.max_resources]
    warmup, window = (1.0, 2.0) if quick else (2.0, 5.0)

    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_station_") as tmp:
        directory = Path(tmp)
        print("(d) baseline: raw zenoh and asyncio Bus ping-pong between two processes ...", flush=True)
        raw = bench_bus.bench_raw(True, round_trips, 1000)
        bus = asyncio.run(bench_bus.bench_bus(True, round_trips, 500))
        print("(a)+(c) a real hub process (one emulated nutrunner, 50 Hz) ...", flush=True)
        hub = asyncio.run(hub_figures(directory, round_trips, footprint_s))
        print("(b) controller capacity, stepping N ...", flush=True)
        results: list[Step] = []
        for n in steps:
            step = asyncio.run(capacity_step(directory, n, warmup, window))
            results.append(step)
            print(f"    N={n}: {'pass' if step.passed else 'FAIL'} (tick median {step.tick_median_ms:.2f} ms, "
                  f"age p99 {step.age_p99_ms:.1f} ms, ingested {step.ingested:,.0f}/s)"
                  + (f" {step.problem}" if step.problem else ""), flush=True)
            if not step.passed:
                break
        print("(e) controller at 500 resources, recording off and on ...", flush=True)
        recording_cost(directory, 1 if quick else args.rounds, warmup, window)

    def ms(values_us: list[float], q: float) -> float:
        return percentile(values_us, q) / 1000

    best = max((s.resources for s in results if s.passed), default=0)
    rtt_p99 = percentile(hub.rtts_ms, 0.99)
    print()
    load = (load_before, os.getloadavg()[0])
    print(f"statehub station benchmark{' (quick)' if quick else ''}: {os.cpu_count()} cores, load average "
          f"{load[0]:.1f} before / {load[1]:.1f} after, {round_trips} round trips, capacity windows {window:.0f} s")
    if load_before > (os.cpu_count() or 1) / 2:
        print("WARNING: the machine was busy with other work before the run; these figures understate statehub")
    print()
    print(f"{'figure':<58} {'measured':>22}   {'target':<14}")
    rows = [
        ("(a) command -> mirror via a hub process: median / p99",
         f"{statistics.median(hub.rtts_ms):.2f} / {rtt_p99:.2f} ms", "p99 < 5 ms", rtt_p99 < 5.0),
        ("(b) controller capacity: resources at 50 Hz (states/s)",
         f"{best} ({best * HUB_RATE_HZ:,.0f}/s)" if best < steps[-1] or not results[-1].passed
         else f">= {best} ({best * HUB_RATE_HZ:,.0f}/s)", ">= 500", best >= 500),
        ("(c) hub, 1 resource at 50 Hz: share of one core",
         f"{100 * hub.cpu_share:.1f} %", "< 3 %", hub.cpu_share < 0.03),
        ("(c) hub, 1 resource at 50 Hz: RSS", f"{hub.rss_mb:.0f} MB", "< 60 MB", hub.rss_mb < 60),
        ("(d) raw zenoh round trip, 2 processes: median / p99",
         f"{ms(raw.rtts_us, 0.5):.2f} / {ms(raw.rtts_us, 0.99):.2f} ms", "(baseline)", None),
        ("(d) asyncio Bus round trip, 2 processes: median / p99",
         f"{ms(bus.rtts_us, 0.5):.2f} / {ms(bus.rtts_us, 0.99):.2f} ms", "(baseline)", None),
    ]
    for name, value, target, ok in rows:
        verdict = "" if ok is None else ("ok" if ok else "MISSED")
        print(f"{name:<58} {value:>22}   {target:<14} {verdict}")
    print()
    print("(b) steps: a step passes with tick median < 5 ms, state age p99 <= 60 ms (3 periods), >= 95 % ingested,")
    print("    every resource healthy; age = hub publication -> controller ingestion; per ~0.25 s status window,")
    print("    tick median = median of the windows' medians, p99/max = worst window; cpu = controller, one core")
    print(f"{'N':>6} {'states/s':>9} {'offered':>9} {'ingested':>9} {'dropped':>8} {'tick':>7} {'tick':>7} "
          f"{'ticks':>6} {'age':>7} {'age':>7} {'age':>7} {'unhl':>5} {'cpu':>6}")
    print(f"{'':>6} {'wanted':>9} {'/s':>9} {'/s':>9} {'':>8} {'med ms':>7} {'p99 ms':>7} {'/s':>6} "
          f"{'med ms':>7} {'p99 ms':>7} {'max ms':>7}")
    for step in results:
        print(step.row())
        for note in step.notes:
            print(f"{'':>6} note: {note}")
    print(f"\n(took {time.perf_counter() - started:.1f} s)")


if __name__ == "__main__":
    main()
