"""What recording costs the controller's ingestion and tick, measured in one process (bench_station.py (e)).

    python tests/bench/bench_recording.py [--resources 500] [--seconds 20]

The controller service of the capacity station (N nutrunners) is built but not connected: batches of
encoded hub states are handed to its ingestion as its subscription hands them over (50 states per
batch: 500 resources at 50 Hz arrive in 2 ms batches), and it ticks after each batch, as on a change.
The CPU time of the whole process (the recording's writer thread included, until its last batch is
on disk) per state ingested is the ingest capacity's inverse. Two loads: `steady` (the values never
change: a state is recorded only when its hub's status or mirror changes) and `changing` (every state
carries a new value: every one is recorded, the worst case). Recording on and off alternate. On a
loaded machine the difference of the two CPU figures is noisy (the machine's load inflates CPU time by
tens of percent from one run to the next), so the recording's own CPU is also counted directly: the
writer thread's CPU time plus the controller thread's inside the recorder's hooks (HookClock).
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
    """The controller thread's CPU time inside the recorder's hooks (the writer thread's is counted apart):
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
                        changing: bool) -> tuple[float, float]:
    """CPU seconds per state ingested (and ticked on), recording or not, and those of the recording's own
    code: the writer thread and the controller thread's time in the recorder's hooks."""
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
    service.recorder.finish("stopped")  # waits for the writer thread: its CPU is counted
    spent = time.process_time() - began
    own_s = getattr(writer, "thread_cpu_s", 0.0) + hooks.seconds
    for task in list(service._solving):
        task.cancel()
    service.store.close()
    await bus.close()
    return spent / (len(batches) * BATCH), own_s / (len(batches) * BATCH)


def measure(resources: int, seconds: float, rounds: int) -> dict[tuple[str, bool], tuple[float, float]]:
    """Median CPU per state for each (load, recording), the process's and the recording's own."""
    os.environ[RESOURCES_ENV] = str(resources)
    states = int(resources * HUB_RATE_HZ * seconds)
    results: dict[tuple[str, bool], list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_recording_") as tmp:
        os.environ[RECORDING_DIR_ENV] = str(Path(tmp) / "runs")
        for _ in range(rounds):
            for load in ("steady", "changing"):
                for record in (False, True):
                    directory = Path(tempfile.mkdtemp(dir=tmp))
                    cost = asyncio.run(cpu_per_state(directory, resources, states, record=record,
                                                     changing=load == "changing"))
                    results.setdefault((load, record), []).append(cost)
        sizes = sorted(p.stat().st_size for p in (Path(tmp) / "runs").glob("*.sqlite"))
    print(f"    recordings written: {len(sizes)}, {sizes[0] / 1024:,.0f} to {sizes[-1] / 1024:,.0f} kB "
          f"for {seconds:.0f} s of states each")
    return {key: (statistics.median(v[0] for v in values), statistics.median(v[1] for v in values))
            for key, values in results.items()}


def report(resources: int, seconds: float, rounds: int, limit: float) -> None:
    figures = measure(resources, seconds, rounds)
    print(f"    {resources} resources x {HUB_RATE_HZ:.0f} Hz, {seconds:.0f} s of states, batches of {BATCH}, a tick "
          f"after each; median of {rounds} rounds; capacity = states per CPU second (writer thread included)")
    for load in ("steady", "changing"):
        (off, _), (on, own) = figures[load, False], figures[load, True]
        cost = 1 - off / on
        print(f"    {load:<9} off {1 / off:>9,.0f} states/cpu-s   on {1 / on:>9,.0f} states/cpu-s   "
              f"on/off x{off / on:.3f}: recording costs {100 * cost:.1f} % "
              f"(target < {100 * limit:.0f} %) {'ok' if cost < limit else 'MISSED'}; "
              f"per state {1e6 * off:.1f} -> {1e6 * on:.1f} us")
        print(f"    {'':<9} the recording's own CPU (writer thread + hooks on the controller thread): "
              f"{1e6 * own:.2f} us per state = {100 * own / off:.1f} % of the off figure")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resources", type=int, default=500)
    parser.add_argument("--seconds", type=float, default=10.0, help="of states at 50 Hz per measurement")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    report(args.resources, args.seconds, args.rounds, 0.05)


if __name__ == "__main__":
    main()
