"""Payloads that must change nothing: garbage, truncated, wrong-schema, other-model and out-of-domain
messages for every key of a fault station, as Hypothesis strategies, and the flood that publishes them."""

from __future__ import annotations

import time
from typing import Any

import msgspec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.wire.ctl import StateSnapshot
from common.wire.messages import SCHEMA, Codec, HubStatus, encode
from hubs.selftest import report_message
from tests.fault_station.harness import Station
from tests.fault_station.model import BOLT_POSES


def message_samples(station: Station) -> dict[str, list[bytes]]:
    """Well-formed payloads of every kind, as published on each key (the basis of truncation)."""
    codecs = station.watch.codecs
    nr, ur = codecs["nr"], codecs["ur"]
    command = {"nr": nr.command({"run_c": False}, seq=1, controller="intruder"),
               "ur": ur.command({"ref_pos_c": "home"}, seq=1, controller="intruder")}
    state = {"nr": nr.state({"run_m": False, "tqr_m": False, "fail_m": False}, status=HubStatus.OK, seq=1, hub="x",
                            mirror=command["nr"]),
             "ur": ur.state({"pos_m": "home", "prot_stop_m": False}, status=HubStatus.OK, seq=1, hub="x",
                            mirror=command["ur"])}
    status = station.watch.status()
    snapshot = StateSnapshot(time=time.time(), values=station.watch.snapshot())
    return {
        "cmd": [codecs[r].encode_command(command[r]) for r in ("nr", "ur")],
        "state": [codecs[r].encode_state(state[r]) for r in ("nr", "ur")],
        "ctl": [encode(status) if status is not None else b"", encode(snapshot)],
        "selftest": [encode(report_message("pi-tool", []))],
    }


def other_model_payload(payload: bytes) -> bytes:
    raw = msgspec.msgpack.decode(payload)
    raw["model_hash"] = "0123456789abcdef"
    if isinstance(raw.get("mirror"), dict):
        raw["mirror"]["model_hash"] = "0123456789abcdef"
    return msgspec.msgpack.encode(raw)


def with_changes(payload: bytes, **changes: Any) -> bytes:
    raw = msgspec.msgpack.decode(payload)
    raw.update(changes)
    return msgspec.msgpack.encode(raw)


def payload_strategy(station: Station) -> st.SearchStrategy[tuple[str, bytes]]:
    keys = station.keys
    samples = message_samples(station)
    by_kind = {
        "cmd": [keys.cmd("nr"), keys.cmd("ur")],
        "state": [keys.state("nr"), keys.state("ur")],
        "ctl": [keys.ctl("status"), keys.ctl("state"), keys.ctl("console", "request")],
        "selftest": [keys.selftest("pi-tool"), keys.selftest("ur10")],
    }
    every_key = [k for ks in by_kind.values() for k in ks]
    every_message = [p for ps in samples.values() for p in ps]
    nr_cmd, ur_cmd = samples["cmd"]
    ints = st.integers(-2**63, 2**64 - 1)  # what MessagePack can carry
    msgpack_values = st.recursive(
        st.none() | st.booleans() | ints | st.floats() | st.text(max_size=20)
        | st.binary(max_size=20),
        lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
        max_leaves=20)
    garbage = st.binary(max_size=300)
    random_msgpack = msgpack_values.map(msgspec.msgpack.encode)
    truncated = st.sampled_from(every_message).flatmap(
        lambda p: st.integers(0, max(0, len(p) - 1)).map(lambda n: p[:n]))
    other_model = st.sampled_from(samples["cmd"] + samples["state"]).map(other_model_payload)
    other_schema = st.sampled_from(every_message).flatmap(
        lambda p: st.sampled_from([0, SCHEMA - 1, SCHEMA + 1, 99, -1, "1", None]).map(
            lambda v: with_changes(p, schema=v)))
    out_of_domain = st.one_of(
        st.one_of(ints, st.text(max_size=10), st.none(), st.floats()).map(lambda v: with_changes(nr_cmd, run_c=v)),
        st.one_of(st.text(max_size=12).filter(lambda t: t not in ("home", *BOLT_POSES.values())), ints,
                  st.booleans()).map(lambda v: with_changes(ur_cmd, ref_pos_c=v)),
    )
    any_payload = st.one_of(garbage, random_msgpack, truncated, other_model, other_schema, out_of_domain)
    # Payloads on every key, and each kind of message aimed at the keys that carry that kind.
    return st.one_of(
        st.tuples(st.sampled_from(every_key), any_payload),
        st.tuples(st.sampled_from(by_kind["cmd"]), st.one_of(out_of_domain, other_model, truncated)),
    )


def flood(station: Station, strategy: st.SearchStrategy[tuple[str, bytes]], examples: int, spacing: float) -> int:
    """Publish `examples` Hypothesis-chosen payloads, `spacing` s apart; every process must stay up."""
    published = [0]

    @settings(max_examples=examples, deadline=None, suppress_health_check=list(HealthCheck))
    @given(strategy)
    def publish(item: tuple[str, bytes]) -> None:
        key, payload = item
        station.watch.publish(key, payload)
        published[0] += 1
        time.sleep(spacing)
        assert not station.dead(), f"{station.dead()} died after {len(payload)} bytes on {key}: {payload[:80]!r}"

    publish()
    return published[0]


def mirror_key(mirror: Any, codec: Codec) -> tuple[Any, ...] | None:
    return None if mirror is None else (mirror.controller, mirror.seq, tuple(codec.values(mirror).items()))
