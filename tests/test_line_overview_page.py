"""The line's overview as a web page (controller/overview/site.py, served by deploy/line/sitepage.py), in a
real headless Chromium: every station listed with its state, product, cycle and health, one unreachable in
alarm, and the page following the line live; read-only (no control on it)."""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import subprocess
import sys
import urllib.request

from selenium.webdriver.common.by import By

from controller.overview.site import SiteFeed
from deploy.line.overview import UNREACHABLE_AFTER_S, Overview, site_picture
from deploy.line.sitepage import served
from tests.browser import chromium
from tests.line_station.page import CONTROLS, station_rows, unreachable_shown, wait_for
from tests.line_station.site import write_line
from tests.test_line_up import status


async def test_the_page_lists_every_station_and_says_which_is_unreachable(tmp_path):
    overview = Overview(["s1", "s2", "s3"])
    feed = SiteFeed("demo")
    s2_seen = 100.0

    async def show(now: float) -> None:
        overview.take("s1", status("p3", 2, (4.5, 4.0)), now)
        overview.take("s3", status(None, 1, (3.0,), sick=True), now)
        await feed.update(site_picture("demo", overview.rows(now), 1, 5))

    overview.take("s2", status("p2", 2, (5.0,), carried={"engine.bolt1_e": "tightened"}), s2_seen)
    await show(s2_seen)
    said: list[str] = []
    async with served(feed, "127.0.0.1:0", said.append) as url:
        assert url is not None, said
        shown: list[dict[str, dict[str, str]]] = []

        def browse() -> None:
            with chromium() as driver:
                driver.get(url)
                wait_for(lambda: len(station_rows(driver)) == 3, 30, "the page lists the 3 stations")
                shown.append(station_rows(driver))
                wait_for(lambda: unreachable_shown(driver, "s2"), 30, "s2 shown unreachable, in alarm")
                shown.append(station_rows(driver))
                driver.save_screenshot(str(tmp_path / "line-overview.png"))
                wait_for(lambda: station_rows(driver)["s2"]["state"] == "working", 30, "s2 shown back")
                assert "unreachable" not in driver.find_element(By.ID, "headline").text
                assert driver.find_elements(By.CSS_SELECTOR, CONTROLS) == []

        browsing = asyncio.create_task(asyncio.to_thread(browse))
        while len(shown) < 1 and not browsing.done():
            await asyncio.sleep(0.1)
        await show(s2_seen + UNREACHABLE_AFTER_S + 1.0)  # s2's statuses stopped: its router is down
        while len(shown) < 2 and not browsing.done():
            await asyncio.sleep(0.1)
        back = s2_seen + UNREACHABLE_AFTER_S + 2.0
        overview.take("s2", status("p2", 2, (5.0,), carried={"engine.bolt1_e": "tightened"}), back)
        await show(back)
        await browsing
    first, alarm = shown
    assert first["s1"]["cells"] == "s1 | working | p3 | 4.0 s | 2 | ok | -"
    assert first["s2"]["cells"] == "s2 | working | p2 | 5.0 s | 2 | ok | 1 value"
    assert (first["s3"]["state"], first["s3"]["cls"]) == ("idle", "warning")
    assert "unhealthy: nr" in first["s3"]["cells"]
    assert (alarm["s1"]["cls"], alarm["s2"]["cls"]) == ("working", "alarm")
    assert (tmp_path / "line-overview.png").stat().st_size > 5_000


def test_hubctl_line_overview_serves_the_page_beside_a_line_and_stops_on_sigterm(tmp_path):
    """`hubctl line overview` on its own: with no router up yet every station is waiting, and the page's data
    says so; SIGTERM ends it with 0."""
    line = write_line(tmp_path, 3)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen([sys.executable, "-m", "deploy.cli", "line", "overview", "--config", str(line),
                                "--bind", f"127.0.0.1:{port}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        assert process.stdout is not None
        first = process.stdout.readline()
        assert f"http://127.0.0.1:{port}/ (read-only; 3 stations)" in first, first
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/site.json", timeout=30) as reply:
            picture = json.loads(reply.read())
        assert [(s["station"], s["state"]) for s in picture["stations"]] == \
            [("s1", "waiting"), ("s2", "waiting"), ("s3", "waiting")]
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=60) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
