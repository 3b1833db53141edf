"""What recording costs the controller's ingestion and tick, measured in one process (bench_station.py (e)).

    python tests/bench/bench_recording.py [--resources 500] [--seconds 20]

The controller service of the capacity station (N nutrunners) is built but not connected: batches of
encoded hub states are handed to its ingestion as its subscription hands them over (50 states per
batch: 500 resources at 50 Hz arrive in 2 ms batches), and it ticks after each batch, as on a change.
The CPU time of the controller's process per state ingested is its ingest capacity's inverse. The
recording's writer is a process of its own (common/recording/writer.py): its CPU time, until the last
record is on disk, is not the controller's and is counted apart, as is the sum of both. Two loads:
`steady` (the values never change: a state is recorded only when its hub's status or mirror changes)
and `changing` (every state carries a new value: every one is recorded, the worst case). Recording on
and off alternate, in turn first. On a loaded machine the difference of the two CPU figures is noisy
(the machine's load inflates CPU time by tens of percent from one run to the next), so the recording's
own CPU is also counted directly: the controller thread's inside the recorder's hooks (HookClock, what
it costs the controller) and the writer process's.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE))

from bench_station_load import HUB_RATE_HZ, RESOURCES_ENV, write_station  # noqa: E402

from common.bus import Sample  # noqa: E402
from common.config import load_station  # noqa: E402
from common.membus import MemoryBus, MemoryHub  # noqa: E402
from common.messages import HubStatus  # noqa: E402
from common.recording.schema import RunMeta  # noqa: E402
from common.recording.writer import RECORDING_DIR_ENV  # noqa: E402
from controller.service import ControllerService  # noqa: E402

BATCH = 50
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


async def cpu_per_state(directory: Path, resources: int, states: int, *, record: bool,
                        changing: bool) -> tuple[float, float, float, float]:
    """CPU seconds per state ingested (and ticked on) of the controller's process, recording or not, and
    those of the recording's own code: the controller thread's in the recorder's hooks, the writer process's
    (without its start); and the seconds the writer process took to start (Python, imports)."""
    config, model = load_station(write_station(directory, f"rec_{os.getpid()}", resources))
    bus = await MemoryBus(MemoryHub()).open()  # commands are published into it, heard by no one
    service = ControllerService(config, model, bus, db=str(directory / "ctl.sqlite"),
                                planner_process=False, record=RunMeta(mode="service") if record else None)
    routes = service._state_routes()
    keys = list(routes)
    payloads = []
    for run_m in (False, True):  # per resource: its state with run_m false and true, mirroring our commands
        row = []
        for key in keys:
            codec = routes[key][1]
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
    hooks = HookClock(service.recorder)
    began = time.process_time()
    for batch in batches:
        service._ingest_batch(batch, routes)
        service._tick()
    writer = service.recorder.sink
    service.recorder.finish("stopped")  # waits for the writer process: it reports its CPU time
    spent = time.process_time() - began
    writer_s = getattr(writer, "process_cpu_s", 0.0)
    start_s = getattr(writer, "process_start_cpu_s", 0.0)
    for task in list(service._solving):
        task.cancel()
    service.store.close()
    await bus.close()
    count = len(batches) * BATCH
    return spent / count, hooks.seconds / count, (writer_s - start_s) / count, start_s


Figures = dict[tuple[str, bool], list[tuple[float, float, float, float]]]


def measure(resources: int, seconds: float, rounds: int) -> Figures:
    """CPU per state for each (load, recording), each round: the controller process's, its hooks', the writer's."""
    os.environ[RESOURCES_ENV] = str(resources)
    states = int(resources * HUB_RATE_HZ * seconds)
    results: Figures = {}
    with tempfile.TemporaryDirectory(prefix="bench_recording_") as tmp:
        os.environ[RECORDING_DIR_ENV] = str(Path(tmp) / "runs")
        for round_ in range(rounds):
            for load in ("steady", "changing"):
                for record in (False, True) if round_ % 2 == 0 else (True, False):
                    directory = Path(tempfile.mkdtemp(dir=tmp))
                    cost = asyncio.run(cpu_per_state(directory, resources, states, record=record,
                                                     changing=load == "changing"))
                    results.setdefault((load, record), []).append(cost)
        sizes = sorted(p.stat().st_size for p in (Path(tmp) / "runs").glob("*.sqlite"))
    print(f"    recordings written: {len(sizes)}, {sizes[0] / 1024:,.0f} to {sizes[-1] / 1024:,.0f} kB "
          f"for {seconds:.0f} s of states each")
    return results


def report(resources: int, seconds: float, rounds: int, limit: float) -> None:
    load_before = os.getloadavg()[0]
    results = measure(resources, seconds, rounds)
    print(f"    {resources} resources x {HUB_RATE_HZ:.0f} Hz, {seconds:.0f} s of states, batches of {BATCH}, a tick "
          f"after each; medians of {rounds} rounds, load average {load_before:.1f} -> {os.getloadavg()[0]:.1f}")
    print("    capacity = states per CPU second of the controller's process; the recording's writer process "
          "is counted apart")
    for load in ("steady", "changing"):
        offs, ons = results[load, False], results[load, True]
        off = statistics.median(r[0] for r in offs)
        on, hooks, writer, start = (statistics.median(r[i] for r in ons) for i in range(4))
        paired = statistics.median(a[0] / b[0] for a, b in zip(offs, ons, strict=True))  # rounds alternate
        both = statistics.median(r[0] + r[2] for r in ons)
        cost = 1 - off / on
        print(f"    {load:<9} off {1 / off:>9,.0f} states/cpu-s   on {1 / on:>9,.0f} states/cpu-s   "
              f"on/off x{off / on:.3f}: recording costs {100 * cost:.1f} % "
              f"(target < {100 * limit:.0f} %) {'ok' if cost < limit else 'MISSED'}; "
              f"per state {1e6 * off:.1f} -> {1e6 * on:.1f} us (round by round: {100 * (1 - paired):.1f} %)")
        print(f"    {'':<9} counted directly: the recorder's hooks on the controller thread {1e6 * hooks:.2f} us per "
              f"state = {100 * hooks / off:.1f} % of the off figure; the writer process {1e6 * writer:.2f} us "
              f"per state (another {100 * writer / off:.1f} %, on another core; {1e3 * start:.0f} ms to start)")
        print(f"    {'':<9} counting the writer process's CPU as the controller's too: {1e6 * both:.1f} us per "
              f"state, x{off / both:.3f} of the capacity recording off ({100 * (1 - off / both):.1f} %)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resources", type=int, default=500)
    parser.add_argument("--seconds", type=float, default=10.0, help="of states at 50 Hz per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    report(args.resources, args.seconds, args.rounds, 0.05)


if __name__ == "__main__":
    main()
