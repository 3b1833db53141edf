"""Status benchmark: the bytes per second on `{station}/ctl/status` during a reference run, on the wire.

    python tests/bench/bench_status.py [--seed N] [--speed S] [--config hubs.toml]
    python tests/bench/bench_status.py --connect tcp/127.0.0.1:PORT   # a station already running

Without `--connect` it runs `hubctl up` (the controller and every hub as processes over Zenoh on
loopback, in a scratch directory) and listens to the controller's status as a console does, every
sample (no coalescing), from the first status to the one that says the run finished. It prints the
samples, their bytes, the largest one, and bytes per second over the run; and what a console pulls
besides on the plan queryable (`{station}/ctl/plan/{id}`, once per plan) when it asks. Nothing is
asserted (tests/test_status_diet.py bounds the bytes per publication).
"""

from __future__ import annotations

import argparse
import asyncio
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from common.bus.zenoh_bus import ZenohBus  # noqa: E402
from common.bus.zenoh_config import zenoh_config  # noqa: E402
from common.config.hubs_toml import load_station  # noqa: E402
from common.wire.ctl import StatusMessage  # noqa: E402
from common.wire.messages import MessageError, decode  # noqa: E402

PORT_LINE = re.compile(r"on 127\.0\.0\.1:(\d+)")


async def measure(station: str, endpoint: str, time_limit: float, pull_plans: bool) -> None:
    from common.wire.keys import station_keys

    keys = station_keys(station)
    async with ZenohBus(zenoh_config("peer", listen=["tcp/127.0.0.1:0"], connect=[endpoint])) as bus:
        statuses = bus.subscribe(keys.ctl("status"), coalesce=False, maxlen=None)
        count = total = largest = full = 0
        plan_bytes = plans = 0
        first_at: float | None = None
        seen_plans: set[int] = set()
        deadline = time.monotonic() + time_limit
        finished = False
        while not finished and time.monotonic() < deadline:
            try:
                sample = await asyncio.wait_for(statuses.get(), 1.0)
            except TimeoutError:
                continue
            now = time.monotonic()
            first_at = first_at if first_at is not None else now
            size = len(sample.payload)
            count, total, largest = count + 1, total + size, max(largest, size)
            try:
                status = decode(sample.payload, StatusMessage)
            except MessageError as exc:
                print(f"undecodable status ({size} bytes): {exc}")
                continue
            full += bool(getattr(status, "full", True))
            finished = status.finished
            plan = getattr(status, "plan", None)
            plan_id = getattr(plan, "id", 0)
            if pull_plans and plan_id and plan_id not in seen_plans:
                seen_plans.add(plan_id)
                for reply in await bus.get(keys.ctl("plan", str(plan_id)), timeout=2.0):
                    plan_bytes, plans = plan_bytes + len(reply.payload), plans + 1
        seconds = (time.monotonic() - first_at) if first_at is not None else 0.0
    if not count:
        print("no status received")
        return
    print(f"ctl/status: {count} samples ({full} full) in {seconds:.1f} s, {total:,} bytes, "
          f"largest {largest:,} bytes, mean {total // count:,} bytes")
    print(f"ctl/status: {total / max(seconds, 1e-9):,.0f} bytes/s{'' if finished else ' (the run did not finish)'}")
    if pull_plans:
        print(f"ctl/plan/{{id}}: {plans} plans pulled, {plan_bytes:,} bytes ({plan_bytes / max(seconds, 1e-9):,.0f} "
              f"bytes/s over the run, for a console that shows the plan)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(ROOT / "hubs.toml"))
    parser.add_argument("--connect", help="measure a station already running (the endpoint `hubctl up` prints)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--time-limit", type=float, default=300.0)
    parser.add_argument("--no-plans", action="store_true", help="do not pull the plan details")
    args = parser.parse_args()
    config, _ = load_station(args.config)
    station = config.station.name
    if args.connect:
        asyncio.run(measure(station, args.connect, args.time_limit, not args.no_plans))
        return 0
    hubctl = Path(sys.executable).parent / "hubctl"
    with tempfile.TemporaryDirectory(prefix="bench_status-") as scratch:
        up = subprocess.Popen([str(hubctl), "up", "--config", str(Path(args.config).resolve()), "--seed",
                               str(args.seed), "--speed", str(args.speed)],
                              cwd=scratch, stdout=subprocess.PIPE, text=True)
        try:
            assert up.stdout is not None
            port = None
            for line in up.stdout:
                found = PORT_LINE.search(line)
                if found:
                    port = found.group(1)
                    break
            if port is None:
                print("hubctl up printed no port")
                return 1
            lines: list[str] = []  # drained meanwhile: a full pipe would stop `hubctl up`
            drain = threading.Thread(target=lambda: lines.extend(up.stdout), daemon=True)  # type: ignore[arg-type]  # stdout is piped
            drain.start()
            asyncio.run(measure(station, f"tcp/127.0.0.1:{port}", args.time_limit, not args.no_plans))
            up.wait(60)
            drain.join(5)
            summary = [line.strip() for line in lines if "finished" in line]
            print("hubctl up:", summary[-1] if summary else f"exit code {up.returncode}")
        finally:
            if up.poll() is None:
                up.terminate()
                up.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
