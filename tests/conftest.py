"""What the tests share. Fixtures here; helpers the test modules import sit beside them
(hub_process.py, deploy_support.py, fault_station/, sim_station/; the driver tests' own
in drivers/conftest.py and drivers/drvtest.py). A free loopback port is `common.process.free_port`,
the one `hubctl up` uses.

The end-to-end runs (a whole station, or hubs as processes driven over Zenoh for seconds) and the
longest property runs (hundreds of planner searches) are marked `slow`: `./dev test --fast` leaves
them out (`pytest -m "not slow"`), `./dev test` runs all.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.hub_process import HubProcess


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The end-to-end runs (marked slow) first: spread over the workers `./dev test` starts, the
    longest then run side by side instead of one of them being the whole run's tail."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session", autouse=True)
def recordings_in_a_temporary_directory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Runs record by default (common/recording): the suite's go to a temporary directory, not ./var/runs
    (controllers started as processes inherit the variable)."""
    from controller.recording.writer import RECORDING_DIR_ENV

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(RECORDING_DIR_ENV, str(tmp_path_factory.mktemp("runs")))
        yield


@pytest.fixture
def hub_process(tmp_path: Path) -> Iterator[Callable[..., HubProcess]]:
    """Start hub processes: `hub_process(config, hub, port, *options)`; each is stopped after the test
    (its log, `<hub>.log` in the test's temporary directory, stays for a post-mortem)."""
    started: list[HubProcess] = []

    def start(config: Path, hub: str, port: int, *options: str) -> HubProcess:
        process = HubProcess(config, hub, port, tmp_path / f"{hub}.log", *options).start()
        started.append(process)
        return process

    yield start
    for process in reversed(started):
        process.stop()
