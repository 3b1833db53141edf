"""The line's overview page as a test reads it in Chromium (tests/test_line_overview_page.py, the slow line
run of tests/test_line_up.py)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webdriver import WebDriver

T = TypeVar("T")
CONTROLS = "form, button, input, select, textarea, a[href]"


def wait_for(check: Callable[[], T | None], timeout: float, what: str) -> T:
    deadline = time.monotonic() + timeout
    while True:
        with_value = check()
        if with_value:
            return with_value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:.0f} s: {what}")
        time.sleep(0.2)


def station_rows(driver: WebDriver) -> dict[str, dict[str, str]]:
    """Each station's row as the page draws it: its state, class and cells."""
    found = driver.execute_script(
        "return [...document.querySelectorAll('#stations tbody tr')].map(tr => ({station: tr.dataset.station, "
        "state: tr.dataset.state, cls: tr.className, cells: [...tr.cells].map(td => td.textContent).join(' | ')}))")
    return {row["station"]: row for row in found}


def unreachable_shown(driver: WebDriver, station: str) -> bool:
    rows = station_rows(driver)
    return station in rows and rows[station]["state"] == "unreachable" and rows[station]["cls"] == "alarm" \
        and f"unreachable: {station}" in driver.find_element(By.ID, "headline").text
