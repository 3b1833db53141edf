"""The capacity station of bench_station.py (b): N emulated nutrunners, and the load generator that serves them.

    python tests/bench/bench_station_load.py ENDPOINT STATION HUB N FIRST STOP

A load generator is one process standing in for one hub (`gen<k>`) of the capacity station:
it publishes the state of the nutrunners FIRST..STOP-1 (of N) at 50 Hz each, spread over the
period, mirrors the newest command of each and holds its hub's liveliness token, until its
stdin closes; then it prints what it sent as JSON. bench_station.py starts one per 250
resources, as a station has several hubs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.bus.zenoh_config import zenoh_config
from common.model import Model
from common.resources import nutrunner
from common.wire.keys import station_keys

RESOURCES_ENV = "STATEHUB_BENCH_RESOURCES"
HUB_RATE_HZ = 50.0
RESOURCES_PER_GENERATOR = 250  # a load generator is one Python process: several share the load, as hubs do


def build_model() -> Model:
    """The capacity station: N nutrunners (N from $STATEHUB_BENCH_RESOURCES), nothing else."""
    n = int(os.environ.get(RESOURCES_ENV, "10"))
    return Model(f"bench_{n}_nutrunners", tuple(nutrunner(f"nr{i}") for i in range(n)))


def generator_slices(resources: int) -> list[range]:
    """The resources of each load generator (each one a hub of the station, `gen<k>`)."""
    count = max(1, -(-resources // RESOURCES_PER_GENERATOR))
    bounds = [resources * k // count for k in range(count + 1)]
    return [range(bounds[k], bounds[k + 1]) for k in range(count)]


def write_station(directory: Path, station: str, resources: int) -> Path:
    lines = [
        "[station]", f'name = "{station}"', 'model = "tests.bench.bench_station_load:build_model"', "",
        "[network]", 'mode = "peer"', "lease_ms = 2000", "",
        "[controller]", 'host = "localhost"', 'name = "bench"', "command_rate_hz = 10", "tick_rate_hz = 20",
        "mirror_timeout_s = 1.0", "stale_after_s = 0.5", "",
    ]
    for k, served in enumerate(generator_slices(resources)):
        lines += [f"[hubs.gen{k}]", 'host = "localhost"', f"rate_hz = {HUB_RATE_HZ}", ""]
        for i in served:
            lines += [f"[hubs.gen{k}.devices.nr{i}]", 'type = "nutrunner"', ""]
    path = directory / f"bench_{resources}.toml"
    path.write_text("\n".join(lines))
    return path


def generator(endpoint: str, station: str, hub: str, resources: int, served: range, rate_hz: float) -> None:
    """Publish the state of the nutrunners `served` (of `resources`) at `rate_hz` each, spread over the period,
    mirroring the newest command of each, until stdin closes; then print what was sent as JSON."""
    import msgspec
    import zenoh

    from common.wire.messages import SCHEMA, Codec, HubStatus, MessageError

    os.environ[RESOURCES_ENV] = str(resources)
    model = build_model()
    keys = station_keys(station)
    codecs = [Codec(model.resources[i]) for i in served]
    session = zenoh.open(zenoh_config("peer", connect=[endpoint]))
    token = session.liveliness().declare_token(keys.alive(hub))
    latest: dict[str, bytes] = {}  # newest command payload per resource, set on zenoh's thread

    def on_command(sample: zenoh.Sample) -> None:
        resource = keys.resource_of(str(sample.key_expr))
        if resource is not None:
            latest[resource] = sample.payload.to_bytes()

    # Declared, as the controller declares the state keys: one process standing in for many hubs
    # otherwise pays zenoh's matching of every command against all the state keys it publishes.
    # (It hears the other generators' commands too: the key layout has no narrower wildcard.)
    keyexprs = [session.declare_keyexpr(keys.cmd(r.name)) for r in model.resources]
    subscriber = session.declare_subscriber(keys.all_cmd, on_command)
    publishers = [session.declare_publisher(keys.state(c.resource), congestion_control=zenoh.CongestionControl.DROP)
                  for c in codecs]
    count = len(codecs)
    mirrors: list[object] = [None] * count
    decoded_from: list[bytes | None] = [None] * count
    encode = msgspec.msgpack.Encoder().encode
    stopped = threading.Event()
    def stop_at_end_of_input() -> None:
        sys.stdin.read()
        stopped.set()

    threading.Thread(target=stop_at_end_of_input, daemon=True).start()
    period = 1.0 / rate_hz
    slots = 10  # publish a tenth of the resources every tenth of the period
    per_slot = -(-count // slots)
    sent, late, seq = 0, 0, 0
    began = next_at = time.monotonic()
    print("ready", flush=True)
    while not stopped.is_set():
        seq += 1
        for slot in range(slots):
            for i in range(slot * per_slot, min(count, (slot + 1) * per_slot)):
                codec = codecs[i]
                payload = latest.get(codec.resource)
                if payload is not None and payload is not decoded_from[i]:
                    with contextlib.suppress(MessageError):
                        mirrors[i] = codec.decode_command(payload)
                    decoded_from[i] = payload
                mirror = mirrors[i]
                state = codec.State(schema=SCHEMA, model_hash=codec.model_hash, run_m=False, tqr_m=False,
                                    fail_m=False, mirror=mirror,
                                    status=HubStatus.OK if mirror is not None else HubStatus.NO_COMMAND,
                                    detail="", seq=seq, time=time.time(), hub=hub)  # as a hub stamps it
                publishers[i].put(encode(state))
                sent += 1
            next_at += period / slots
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:
                late += 1
                next_at = time.monotonic()
    elapsed = time.monotonic() - began
    subscriber.undeclare()
    for keyexpr in keyexprs:
        session.undeclare(keyexpr)
    token.undeclare()
    session.close()
    print(json.dumps({"sent": sent, "elapsed": elapsed, "late_periods": late}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("endpoint")
    parser.add_argument("station")
    parser.add_argument("hub")
    parser.add_argument("resources", type=int)
    parser.add_argument("first", type=int)
    parser.add_argument("stop", type=int)
    args = parser.parse_args()
    generator(args.endpoint, args.station, args.hub, args.resources, range(args.first, args.stop), HUB_RATE_HZ)


if __name__ == "__main__":
    main()
