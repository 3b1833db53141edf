"""End to end: the operator's hub as a process with the page driver (mode real), an emulated robot's
hub and the controller, over Zenoh on loopback; Chromium plays the operator, calls the supervisor (the
controller's event log shows the call and its end) and clicks Confirm, and the operation finishes."""

from __future__ import annotations

from pathlib import Path

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from common.plumbing.lifecycle import free_port
from common.wire.ctl import SupervisorCalled, SupervisorCallEnded
from tests.browser import chromium
from tests.fault_station.harness import Station, write_config

TEMPLATE = Path(__file__).with_name("operator_station") / "hubs.toml"
WAIT_S = 60.0


@pytest.mark.slow
def test_the_operator_confirms_in_the_browser_and_the_operation_finishes(tmp_path: Path) -> None:
    port = free_port()
    config = write_config(tmp_path, TEMPLATE, prefix="operator", replace=[("port = 18080", f"port = {port}")])
    with Station(tmp_path, config=config) as station, chromium() as browser:
        station.start(timeout=60)
        browser.get(f"http://127.0.0.1:{port}/")
        wait = WebDriverWait(browser, WAIT_S, poll_frequency=0.05)
        wait.until(lambda b: "Fit the part the robot holds" in b.find_element(By.ID, "instruction").text,
                   message="the instruction never showed")
        assert browser.find_element(By.ID, "step").text == "Step 1 of 1"
        # The robot brings the part: Confirm is enabled once the hub sees it at the part.
        wait.until(lambda b: b.find_element(By.ID, "confirm").is_enabled(), message="Confirm never enabled")
        assert not station.watch.finished()
        browser.find_element(By.ID, "call").click()
        station.wait_for(lambda: called(station, SupervisorCalled), WAIT_S, "the call in the controller's events")
        wait.until(lambda b: b.find_element(By.ID, "call").text == "Supervisor called",
                   message="the page never showed the call")
        browser.find_element(By.ID, "confirm").click()
        station.wait_for(station.watch.finished, WAIT_S, "the operation finishes")
        station.wait_for(lambda: station.watch.snapshot().get("cell.part_e") == "fitted", WAIT_S,
                         "the controller records the part fitted")
        # The instruction withdrawn, the button released: the page says so.
        wait.until(lambda b: "No instruction" in b.find_element(By.ID, "instruction").text,
                   message="the instruction was never withdrawn on the page")
        wait.until(lambda b: "human has no instruction to confirm" in b.find_element(By.ID, "reason").text,
                   message="the button's reason never came back")
        # The station moved on: the call is over, for the controller too.
        station.wait_for(lambda: called(station, SupervisorCallEnded), WAIT_S, "the call's end in the events")


def called(station: Station, kind: type[SupervisorCalled | SupervisorCallEnded]) -> bool:
    status = station.watch.status()
    return status is not None and any(isinstance(event, kind) and (event.hub, event.resource) == ("human", "human")
                                      for event in status.events)
