"""The controller's state ingestion: a batch of states (newest per resource) decoded and merged at once.

The controller is built on the fault-test station but not run: batches are handed to it
directly, as its state subscription hands them over (tests/test_bus.py covers the batching).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from common.bus.protocol import Sample
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.wire.messages import HubStatus
from controller.service import ControllerService

STATION = Path(__file__).resolve().parent / "fault_station" / "hubs.toml"


@pytest.fixture
async def service(tmp_path: Path) -> AsyncIterator[ControllerService]:
    config, model = load_station(STATION)
    async with ZenohBus(zenoh_config("peer")) as bus:
        service = ControllerService(config, model, bus, db=str(tmp_path / "controller.sqlite"),
                                    planner_process=False)
        try:
            yield service
        finally:
            service.store.close()


def nr_state(service: ControllerService, run_m: bool | None, seq: int) -> bytes:
    codec = service.codecs["nr"]
    # seq 0, the first command's: the controller may have sent it, so the mirror is not a forged one
    command = codec.command({"run_c": bool(run_m)}, seq=0, controller=service.controller_id)
    return codec.encode_state(codec.state({"run_m": run_m, "tqr_m": False, "fail_m": False}, status=HubStatus.OK,
                                          seq=seq, hub="pi-tool", mirror=command))


async def test_a_batch_is_merged_and_a_malformed_state_is_dropped_and_logged_once(
        service: ControllerService, caplog: pytest.LogCaptureFixture) -> None:
    keys = service.config.keys
    assert set(service.ingest.routes) == {keys.state("nr"), keys.state("ur")}
    index = service.compiled.index
    ur_before = service.core.state[index["ur.pos_m"]]
    batch = [Sample(keys.state("ur"), b"\x93garbage"),  # not a state: dropped, the rest of the batch stands
             Sample(keys.state("nr"), nr_state(service, True, 7)),
             Sample(keys.ctl("status"), b"")]  # not a resource's state key: ignored
    with caplog.at_level(logging.WARNING, logger="statehub.controller"):
        changed = service.ingest.batch(batch)
        service.ingest.batch(batch)
    assert service.core.state[index["nr.run_m"]] is True
    assert service.core.state[index["ur.pos_m"]] == ur_before
    assert changed  # the service ticks
    dropped = [r.getMessage() for r in caplog.records if "dropped state" in r.getMessage()]
    assert len(dropped) == 1 and keys.state("ur") in dropped[0]  # logged once per key and interval
    # The watchdog heard from nr (mirroring our seq 0), not from ur; nr's mirror was taken once.
    assert service.watchdog.watches["nr"].mirrored_seq == 0 and service.watchdog.watches["nr"].ever_seen
    assert not service.watchdog.watches["ur"].ever_seen
    assert service.ingest.mirrors == {"nr": {"run_c": True}}
    assert len(service.meter.ages) == 2


async def test_an_unknown_value_keeps_the_last_known_one_and_no_change_asks_for_no_tick(
        service: ControllerService) -> None:
    keys = service.config.keys
    index = service.compiled.index
    assert service.ingest.batch([Sample(keys.state("nr"), nr_state(service, True, 1))])
    changed = service.ingest.batch([Sample(keys.state("nr"), nr_state(service, None, 2))])  # device lost: unknown
    assert service.core.state[index["nr.run_m"]] is True
    assert not changed
