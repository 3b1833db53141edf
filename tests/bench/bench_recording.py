"""What recording costs the controller's ingestion and tick, measured without Zenoh (bench_station.py (e)).

    python tests/bench/bench_recording.py [--resources 500] [--seconds 20]

The controller service of the capacity station (N nutrunners) is built but not connected: batches of
encoded hub states are handed to its ingestion as its subscription hands them over (50 states per
batch: 500 resources at 50 Hz arrive in 2 ms batches), and it ticks after each batch, as on a change.
The CPU time of the controller's process per state ingested is its ingest capacity's inverse. The
recording's writer is a process of its own (controller/recording/writer.py): its CPU time, until the last
record is on disk, is not the controller's and is counted apart, as is the sum of both. Two loads:
`steady` (the values never change: a state is recorded only when its hub's status or mirror changes)
and `changing` (every state carries a new value: every one is recorded, the worst case). Recording on
and off alternate, in turn first, each measurement in a fresh process; the figure is the median of the
rounds' own. From one measurement to the next the CPU per state varies by several percent, even on an
idle machine (off against off: up to 6 %), so two steadier figures are printed beside it: the
recording's own CPU counted directly (the controller thread's inside the recorder's hooks, HookClock,
and the writer process's), and the cost measured on one service whose recording is attached and
detached in turn every BLOCK batches (`interleaved`).
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))


from common.bus.memory_bus import MemoryBus, MemoryHub  # noqa: E402
from common.bus.protocol import Sample  # noqa: E402
from common.config.hubs_toml import load_station  # noqa: E402
from common.wire.messages import HubStatus  # noqa: E402
from controller.recording.schema import (  # noqa: E402
    RunMeta,
    RunMode,
    RunOutcome,
)
from controller.recording.writer import RECORDING_DIR_ENV  # noqa: E402
from controller.service import ControllerService  # noqa: E402
from tests.bench.bench_station_load import HUB_RATE_HZ, RESOURCES_ENV, write_station  # noqa: E402

BATCH = 50
BLOCK = 100  # batches between attaching and detaching the recording (interleaved)
HOOKS = ("ingested", "liveliness", "ticked", "request", "command", "plan_request", "plan", "loaded", "unknown_set")


class HookClock:
    """The controller thread's CPU time inside the recorder's hooks (the writer process's is counted apart):
    what recording costs measured directly, steadier on a loaded machine than on minus off."""

    def __init__(self, recorder: object) -> None:
        self.seconds = 0.0
        for name in HOOKS:
            setattr(recorder, name, self._timed(getattr(recorder, name)))

    def _timed(self, hook: Callable[..., None]) -> Callable[..., None]:
        def timed(*args: object, **kwargs: object) -> None:
            began = time.thread_time()
            hook(*args, **kwargs)
            self.seconds += time.thread_time() - began
        return timed


async def _service(directory: Path, resources: int, states: int, *, record: bool, changing: bool
                   ) -> tuple[ControllerService, list[list[Sample]], MemoryBus]:
    """The capacity station's controller service, ready to ingest, and the batches of states it will take."""
    config, model = load_station(write_station(directory, f"rec_{os.getpid()}", resources))
    bus = await MemoryBus(MemoryHub()).open()  # commands are published into it, heard by no one
    service = ControllerService(config, model, bus, db=str(directory / "ctl.sqlite"),
                                planner_process=False, record=RunMeta(mode=RunMode.SERVICE) if record else None)
    routes = service.ingest.routes
    keys = list(routes)
    payloads = []
    for run_m in (False, True):  # per resource: its state with run_m false and true, mirroring our commands
        row = []
        for key in keys:
            codec = routes[key].codec
            mirror = codec.command({"run_c": False}, seq=0, controller=service.controller_id)
            row.append(codec.encode_state(codec.state({"run_m": run_m, "tqr_m": False, "fail_m": False},
                                                      status=HubStatus.OK, seq=1, hub="gen", mirror=mirror)))
        payloads.append(row)
    batches = []
    for b in range(states // BATCH):
        first = b * BATCH % len(keys)
        flip = (b * BATCH // len(keys)) % 2 if changing else 0  # each round over the resources flips run_m
        batches.append([Sample(keys[(first + i) % len(keys)], payloads[flip][(first + i) % len(keys)])
                        for i in range(BATCH)])
    service._restore()
    await service.station_hold.acquire()  # its epoch goes with every command sent
    # From a collected heap: the set-up's garbage is not collected, and counted, inside the measurement
    # (in one process for all measurements, the service of the one before made the next ~6 % slower).
    gc.collect()
    return service, batches, bus


async def _close(service: ControllerService, bus: MemoryBus) -> None:
    for task in service.planning.tasks():
        task.cancel()
    service.store.close()
    await bus.close()


async def cpu_per_state(directory: Path, resources: int, states: int, *, record: bool,
                        changing: bool) -> tuple[float, float, float, float]:
    """CPU seconds per state ingested (and ticked on) of the controller's process, recording or not, and
    those of the recording's own code: the controller thread's in the recorder's hooks, the writer process's
    (without its start); and the seconds the writer process took to start (Python, imports)."""
    service, batches, bus = await _service(directory, resources, states, record=record, changing=changing)
    hooks = HookClock(service.recorder)
    began = time.process_time()
    for batch in batches:
        service.ingest.batch(batch)
        service._tick()
    writer = service.recorder.sink
    service.recorder.finish(RunOutcome.STOPPED)  # waits for the writer process: it reports its CPU time
    spent = time.process_time() - began
    writer_s = getattr(writer, "process_cpu_s", 0.0)
    start_s = getattr(writer, "process_start_cpu_s", 0.0)
    await _close(service, bus)
    count = len(batches) * BATCH
    return spent / count, hooks.seconds / count, (writer_s - start_s) / count, start_s


async def interleaved(directory: Path, resources: int, states: int, *, changing: bool) -> float:
    """1 - capacity on / off of one service whose recording is attached and detached in turn every BLOCK
    batches: both see the same heap and the same moment's load (separate measurements differ by several
    percent from one to the next in both). Detached, the recorder's hooks return at once, as with
    `--no-record`. The writer process works on while the recording is detached, so what it does to the
    controller's caches is shared by both: a cross-check of the figure above, not a replacement. (It would
    not do for a writer thread in the controller's process: its CPU in a detached block would count as off.)"""
    service, batches, bus = await _service(directory, resources, states, record=True, changing=changing)
    recorder, sink = service.recorder, service.recorder.sink
    spent = {False: 0.0, True: 0.0}
    for block, start in enumerate(range(0, len(batches) - len(batches) % (2 * BLOCK), BLOCK)):
        record = block % 2 == 1
        recorder.sink = sink if record else None
        began = time.process_time()
        for batch in batches[start:start + BLOCK]:
            service.ingest.batch(batch)
            service._tick()
        if block >= 2:  # the first two warm up
            spent[record] += time.process_time() - began
    recorder.sink = sink
    recorder.finish(RunOutcome.STOPPED)
    await _close(service, bus)
    return 1 - spent[False] / spent[True]


Figures = dict[tuple[str, bool], list[tuple[float, float, float, float]]]


def measure(resources: int, seconds: float, rounds: int) -> tuple[Figures, dict[str, list[float]]]:
    """CPU per state for each (load, recording), each round: the controller process's, its hooks', the writer's;
    and each round's interleaved figure per load. Each measurement runs in a fresh process: in one process
    the later ones ran on the heap the earlier ones left, which made a configuration several percent
    slower or faster than another for no reason of its own (off against off: up to 6 %)."""
    states = int(resources * HUB_RATE_HZ * seconds)
    results: Figures = {}
    mixed: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_recording_") as tmp:
        env = {**os.environ, RECORDING_DIR_ENV: str(Path(tmp) / "runs")}

        def run(what: str, load: str) -> list[float]:
            directory = tempfile.mkdtemp(dir=tmp)
            done = subprocess.run([sys.executable, __file__, "--one", what, load, "--resources", str(resources),
                                   "--states", str(states), "--dir", directory],
                                  env=env, capture_output=True, text=True, check=True)
            return list(json.loads(done.stdout.splitlines()[-1]))

        for round_ in range(rounds):
            for load in ("steady", "changing"):
                for what in ("off", "on") if round_ % 2 == 0 else ("on", "off"):
                    results.setdefault((load, what == "on"), []).append(tuple(run(what, load)))  # type: ignore[arg-type]  # a pair of floats
                mixed.setdefault(load, []).append(run("interleaved", load)[0])
        sizes = sorted(p.stat().st_size for p in (Path(tmp) / "runs").glob("*.sqlite"))
    print(f"    recordings written: {len(sizes)}, {sizes[0] / 1024:,.0f} to {sizes[-1] / 1024:,.0f} kB "
          f"for {seconds:.0f} s of states each")
    return results, mixed


def one(what: str, load: str, resources: int, states: int, directory: Path) -> list[float]:
    """One measurement (`--one`): `off`, `on` (cpu_per_state) or `interleaved`."""
    os.environ[RESOURCES_ENV] = str(resources)
    changing = load == "changing"
    if what == "interleaved":
        return [asyncio.run(interleaved(directory, resources, states, changing=changing))]
    return list(asyncio.run(cpu_per_state(directory, resources, states, record=what == "on", changing=changing)))


def report(resources: int, seconds: float, rounds: int, limit: float) -> None:
    load_before = os.getloadavg()[0]
    results, mixed = measure(resources, seconds, rounds)
    print(f"    {resources} resources x {HUB_RATE_HZ:.0f} Hz, {seconds:.0f} s of states, batches of {BATCH}, a tick "
          f"after each; {rounds} rounds, load average {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
    print("    capacity = states per CPU second of the controller's process (the recording's writer process is "
          "counted apart); recording costs = 1 - capacity on / off, the median of the rounds' own figures (each "
          "round measures off and on back to back, in turn first, each in a fresh process)")
    for load in ("steady", "changing"):
        offs, ons = results[load, False], results[load, True]
        off = statistics.median(r[0] for r in offs)
        on, hooks, writer, start = (statistics.median(r[i] for r in ons) for i in range(4))
        pairs = list(zip(offs, ons, strict=True))
        costs = [1 - a[0] / b[0] for a, b in pairs]
        cost = statistics.median(costs)
        both = statistics.median(1 - a[0] / (b[0] + b[2]) for a, b in pairs)
        verdict = "ok" if cost < limit else "MISSED"
        print(f"    {load:<9} off {1 / off:>9,.0f} states/cpu-s   on {1 / on:>9,.0f} states/cpu-s (medians): "
              f"recording costs {100 * cost:.1f} % (target < {100 * limit:.0f} %) {verdict}; "
              f"per state {1e6 * off:.1f} -> {1e6 * on:.1f} us (the medians' ratio: {100 * (1 - off / on):.1f} %)")
        print(f"    {'':<9} the rounds' figures, in order (off first, on first, ...): "
              f"{', '.join(f'{100 * c:.1f}' for c in costs)} %")
        print(f"    {'':<9} counted directly: the recorder's hooks on the controller thread {1e6 * hooks:.2f} us per "
              f"state = {100 * hooks / off:.1f} % of the off figure; the writer process {1e6 * writer:.2f} us "
              f"per state (another {100 * writer / off:.1f} %, on another core; and {1e3 * start:.0f} ms to start)")
        print(f"    {'':<9} counting the writer process's CPU (but its start) as the controller's too: recording "
              f"costs {100 * both:.1f} %")
        print(f"    {'':<9} interleaved on one service (recording attached and detached every {BLOCK} batches): "
              f"recording costs {100 * statistics.median(mixed[load]):.1f} %; the rounds': "
              f"{', '.join(f'{100 * c:.1f}' for c in mixed[load])} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resources", type=int, default=500)
    parser.add_argument("--seconds", type=float, default=10.0, help="of states at 50 Hz per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--one", nargs=2, metavar=("off|on|interleaved", "steady|changing"), help=argparse.SUPPRESS)
    parser.add_argument("--states", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--dir", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:  # a measurement of measure()'s, in a process of its own
        what, load = args.one
        print(json.dumps(one(what, load, args.resources, args.states, args.dir)))
        return
    report(args.resources, args.seconds, args.rounds, 0.05)


if __name__ == "__main__":
    main()
