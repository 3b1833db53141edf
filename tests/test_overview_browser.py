"""The overview page in a real headless Chromium (tests/browser.py), served by the `hubctl overview` process.

* `test_overview_follows_a_running_station`: the fault station (tests/fault_station: a robot and its
  nutrunner tighten 4 bolts) as real processes over Zenoh, slowed to a quarter of its speed; the page
  shows the operations' states change, the Gantt chart grow, and the nutrunner in alarm once its hub
  is killed; it has nothing a person could press or submit, and fits 1280x800 without scrolling sideways.
* `test_overview_sends_nothing_on_the_wire`: the overview alone with a spy playing the controller, which
  sees every put and every query on the station's keys while a browser shows the page and clicks on
  everything: the overview's only traffic is queries of the status and the plan.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webdriver import WebDriver

from common.bus.protocol import Request
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.model import OperationState
from common.plumbing.lifecycle import free_port
from common.wire.ctl import OperationInfo, PlanDetails, PlanInfo, PlanStepInfo, ResourceHealthInfo, StatusMessage
from common.wire.messages import encode
from tests.browser import chromium
from tests.fault_station.harness import ROOT, Station, write_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

CONTROLS = "form, button, input, select, textarea, a[href], [onclick], [contenteditable]"
T = TypeVar("T")


def wait(predicate: Callable[[], T | None], timeout: float, what: str, describe: Callable[[], str] = lambda: "") -> T:
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s; {describe()}")
        time.sleep(0.1)


@dataclass
class Overview:
    process: subprocess.Popen[bytes]
    url: str
    log: Path

    def tail(self) -> str:
        return self.log.read_text(errors="replace")[-3000:] if self.log.exists() else "(no log)"


@contextlib.contextmanager
def overview(config: Path, controller_port: int, directory: Path) -> Iterator[Overview]:
    """`python -m controller.overview` (what `hubctl overview` runs), until it answers on its port. It finds the
    run's recordings where the controller writes them (tests/conftest.py sets $STATEHUB_RECORDING_DIR)."""
    port = free_port()
    log = directory / "overview.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    argv = [sys.executable, "-m", "controller.overview", "--config", str(config), "--bind", f"127.0.0.1:{port}",
            "--connect", f"tcp/127.0.0.1:{controller_port}"]
    with log.open("wb") as handle:
        process = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=handle, stderr=subprocess.STDOUT,
                                   start_new_session=True)
    served = Overview(process, f"http://127.0.0.1:{port}/", log)

    def answers() -> bool:
        if process.poll() is not None:
            raise AssertionError(f"the overview exited with {process.returncode}:\n{served.tail()}")
        with contextlib.suppress(OSError), urllib.request.urlopen(served.url + "picture.json", timeout=2) as response:
            return bool(response.status == 200)
        return False

    try:
        wait(answers, 60, "the overview serves its page", served.tail)
        yield served
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(10)
        print(f"\n----- overview ({log}) -----\n{served.tail()}")


def rows(driver: WebDriver, table: str) -> list[dict[str, str]]:
    """The rows of a table as the page shows them: their data attributes, class and cells."""
    script = """return Array.from(document.querySelectorAll(arguments[0] + ' tbody tr')).map(tr => Object.assign(
        {cls: tr.className, cells: Array.from(tr.cells).map(td => td.textContent).join(' | ')}, tr.dataset));"""
    return list(driver.execute_script(script, table))


def gantt_size(driver: WebDriver) -> tuple[float, int]:
    """(the run's end in seconds, bars drawn) of the Gantt chart on the page."""
    end = driver.execute_script("return document.getElementById('gantt-summary').dataset.end || '0'")
    bars = driver.execute_script("return document.querySelectorAll('#gantt rect.span').length")
    return float(end), int(bars)


def test_overview_follows_a_running_station(tmp_path: Path) -> None:
    config = write_config(tmp_path, prefix="overview")
    with Station(tmp_path, config=config, speed=0.25) as station, \
            overview(config, station.port, tmp_path) as served, chromium() as driver:
        driver.get(served.url)
        wait(lambda: "no status" in driver.find_element(By.ID, "headline").text, 30,
             "the page says the controller is not heard before it starts")
        station.start()
        describe = station.describe

        def ops() -> dict[str, str]:
            return {r["name"]: r["state"] for r in rows(driver, "#operations")}

        wait(lambda: len(ops()) == 4, 30, "the page shows the 4 operations", describe)
        wait(lambda: OperationState.EXECUTING in ops().values(), 30, "an operation shown executing", describe)
        wait(lambda: OperationState.FINISHED in ops().values(), 60, "an operation shown finished", describe)
        goals = {r["name"]: r["cells"] for r in rows(driver, "#operations")}
        assert "engine.bolt4_e == tightened" in goals["TightenBolt4"]

        def drawn() -> tuple[float, int] | None:
            size = gantt_size(driver)
            return size if size[1] else None

        first = wait(drawn, 30, "the Gantt chart drawn", describe)
        wait(lambda: gantt_size(driver)[0] > first[0] and gantt_size(driver)[1] > first[1], 60,
             f"the Gantt chart grows (it was {first})", describe)
        assert {r["resource"] for r in rows(driver, "#resources")} == {"nr", "ur"}
        assert all(r["cls"] == "normal" for r in rows(driver, "#resources"))
        driver.save_screenshot(str(tmp_path / "overview-running.png"))

        station.kill("pi-tool")

        def nr_row() -> dict[str, str]:
            return next(r for r in rows(driver, "#resources") if r["resource"] == "nr")

        wait(lambda: nr_row()["cls"] == "alarm", 30, "the killed hub's nutrunner shown in alarm", describe)
        assert "pi-tool" in nr_row()["cells"].split(" | ")[3]  # the watchdog's reason, not "ok"
        ur = next(r for r in rows(driver, "#resources") if r["resource"] == "ur")
        assert ur["cls"] == "normal", ur
        driver.save_screenshot(str(tmp_path / "overview-alarm.png"))
        assert (tmp_path / "overview-alarm.png").stat().st_size > 10_000  # drawn, not a blank page

        assert driver.find_elements(By.CSS_SELECTOR, CONTROLS) == []
        width = driver.execute_script("return document.documentElement.scrollWidth")
        assert width <= 1280, f"the page is {width} px wide: it scrolls sideways at 1280x800"


# --- on the wire -------------------------------------------------------------------------------------

async def test_overview_sends_nothing_on_the_wire(tmp_path: Path) -> None:
    config_path = write_config(tmp_path, prefix="overview_wire")
    config, _ = load_station(config_path)
    keys = config.keys
    port = free_port()
    published: set[bytes] = set()
    heard: list[tuple[str, bytes]] = []
    queries: list[str] = []
    plan = PlanInfo(id=1, goals=["engine.bolt1_e == tightened"], steps=1)
    details = PlanDetails(id=1, goals=plan.goals, current=True,
                          steps=[PlanStepInfo("nr", "nr.start", "deliberate", "ur.pos_m == at_bolt1", False)])

    def status(seq: int) -> StatusMessage:
        return StatusMessage(station=keys.station, controller="spy", time=time.time(), uptime=seq * 0.25, seq=seq,
                             operations=[OperationInfo("TightenBolt1", OperationState.EXECUTING)],
                             health=[ResourceHealthInfo("nr", "pi-tool", True, age=0.1)], plan=plan)

    async def answer(request: Request) -> bytes | None:
        queries.append(request.key)
        if request.key == keys.ctl("status"):
            return encode(status(0))
        if request.key == keys.plan(1):
            return encode(details)
        return None

    async def listen(bus: ZenohBus) -> None:
        async for sample in bus.subscribe(f"{keys.station}/**", coalesce=False, maxlen=None):
            heard.append((sample.key, sample.payload))

    spy_config = zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"], connect=[], lease_ms=1000)
    async with ZenohBus(spy_config) as spy:
        spy.declare_queryable(f"{keys.station}/**", answer)
        listening = asyncio.create_task(listen(spy))
        with overview(config_path, port, tmp_path) as served:
            def browse() -> list[str]:
                with chromium() as driver:
                    driver.get(served.url)
                    wait(lambda: rows(driver, "#plan"), 60, "the page shows the spy's plan step")
                    for element in driver.find_elements(By.CSS_SELECTOR, "body *"):
                        with contextlib.suppress(Exception):
                            element.click()
                    return [r["cells"] for r in rows(driver, "#plan")]

            browsing = asyncio.create_task(asyncio.to_thread(browse))
            seq = 0
            while not browsing.done():
                seq += 1
                payload = encode(status(seq))
                published.add(payload)
                spy.publish(keys.ctl("status"), payload)
                await asyncio.sleep(0.25)
            shown = await browsing
            await asyncio.sleep(1.0)  # anything the clicks could have caused has arrived by now
        listening.cancel()
        await asyncio.gather(listening, return_exceptions=True)
    assert "ur.pos_m == at_bolt1" in shown[0]  # the plan's details came by the overview's query
    others = [(key, len(payload)) for key, payload in heard if key != keys.ctl("status") or payload not in published]
    assert others == [], f"the overview put on the station's keys: {others}"
    assert keys.ctl("status") in queries and keys.plan(1) in queries, queries
    assert set(queries) <= {keys.ctl("status"), keys.plan(1)}, f"the overview asked more than it reads: {queries}"
    assert json.dumps(sorted(set(queries)))  # what it asked, for the log of a failing run
