"""`hubctl line up`: the overview's verdicts, and a whole line of real processes over two routers, one of them
killed and restarted mid-run (slow)."""

from __future__ import annotations

import asyncio
import json
import sqlite3
from pathlib import Path

import pytest

from common.wire.ctl import OrderDone, ProductionInfo, ResourceHealthInfo, StatusMessage
from common.wire.orders import Order, ParameterValue
from deploy.line.overview import UNREACHABLE_AFTER_S, Overview, StationState
from deploy.line.up import Kill, LineOptions, LineResult, run_line
from tests.browser import chromium
from tests.line_station.model import bolt
from tests.line_station.page import station_rows, unreachable_shown, wait_for
from tests.line_station.site import write_line


def status(current: str | None, done: int = 0, cycles: tuple[float, ...] = (), sick: bool = False,
           carried: dict[str, ParameterValue] | None = None) -> StatusMessage:
    production = ProductionInfo(
        current=None if current is None else Order(id=done + 1, product_id=current, variant="default",
                                                   carried=carried or {}),
        done=done, recent=[OrderDone(i, f"p{i}", "default", 0.0, c) for i, c in enumerate(cycles)])
    health = [ResourceHealthInfo("nr", "pi-tool", not sick, "stale" if sick else "")]
    return StatusMessage(station="s", controller="c", time=0.0, uptime=0.0, production=production, health=health)


def test_the_overview_says_state_product_cycle_health_and_unreachable():
    overview = Overview(["s1", "s2", "s3"])
    overview.take("s1", status("p2", 1, (4.5,)), now=10.0)
    overview.take("s2", status(None, 3, (1.0, 2.0), sick=True), now=10.0)
    rows = {r.station: r for r in overview.rows(now=11.0)}
    assert (rows["s1"].state, rows["s1"].product, rows["s1"].cycle_s, rows["s1"].done) == \
        (StationState.WORKING, "p2", 4.5, 1)
    assert (rows["s2"].state, rows["s2"].unhealthy) == (StationState.IDLE, ("nr",))
    assert rows["s3"].state is StationState.WAITING
    later = 10.0 + UNREACHABLE_AFTER_S + 0.1
    assert overview.unreachable(later) == ["s1", "s2"]
    overview.take("s1", status("p2", 1, (4.5,)), now=later)
    assert overview.unreachable(later) == ["s2"]
    assert "UNHEALTHY nr" in rows["s2"].text()


def test_the_overview_shows_the_state_the_current_product_carried_in():
    overview = Overview(["s1", "s2"])
    overview.take("s1", status("p1"), now=1.0)
    overview.take("s2", status("p0", carried={"engine.bolt1_e": "tightened", "engine.bolt2_e": "tightened"}), now=1.0)
    rows = {r.station: r for r in overview.rows(now=1.5)}
    assert rows["s2"].carried == {"engine.bolt1_e": "tightened", "engine.bolt2_e": "tightened"}
    assert rows["s2"].text().endswith("ok  carried 2 values") and "carried" not in rows["s1"].text()


# Router r2 (station s2's) once a product left s1 (it restarts 5 s later); then the line controller and s2's
# controller (each restarts after 1 s, from its SQLite file).
KILLS = (Kill("router r2", 1), Kill("line controller", 3), Kill("s2 controller", 4))


@pytest.mark.slow
async def test_a_line_of_three_stations_survives_a_router_restart(tmp_path):
    """3 stations over two routers, 5 products, KILLS on the way: s1 and s3 go on while r2 is down, s2 is
    unreachable meanwhile and its handovers wait; every product leaves s3 and each station did every operation
    of every product once."""
    line = write_line(tmp_path, 3)
    said: list[str] = []
    running = run_line(LineOptions(config=str(line), products=5, run_dir=tmp_path / "run", time_limit=300,
                                   overview_every_s=5.0, kills=KILLS, overview_bind="127.0.0.1:0"), said.append)
    # the line runs to its end whatever the browser saw: no process of it outlives the test
    result, page = await asyncio.gather(running, asyncio.to_thread(watch_the_page, said, tmp_path),
                                        return_exceptions=True)
    text = "\n".join(said)
    assert isinstance(result, LineResult), result
    if isinstance(page, BaseException):
        raise AssertionError(f"the page: {page}\n{text}") from page
    # the overview's web page listed the 3 stations and showed s2 unreachable while router r2 was down
    assert set(page) == {"s1", "s2", "s3"} and page["s2"]["state"] == "unreachable", page
    assert result.finished, text
    assert (result.products_done, result.products) == (5, 5)
    assert (result.restarts["router r2"], result.restarts["line controller"], result.restarts["s2 controller"]) \
        == (1, 1, 1), text
    assert "KILLED router r2" in text
    assert result.unreachable_seen.get("s2", 0) >= 1, text  # the overview said it could not reach s2
    line_log = (tmp_path / "run" / "line-controller.log").read_text()
    assert "station s2 unreachable: its handovers wait" in line_log  # and the line controller waited
    assert "station s2 reachable again" in line_log
    assert set(result.done_once) == {"s1", "s2", "s3"}
    for station, done in result.done_once.items():
        assert done.finishes, (station, done.text())
        assert not done.redone(), (station, done.text())
        # each of the 2 operations finished once per product: 5 times, with the 4 resets between products
        assert done.finishes == {"TightenBolt1": 5, "TightenBolt2": 5}, (station, done.text())
    assert [r.done for r in result.last_rows] == [5, 5, 5]
    # each product carried its state from station to station: s1's archive (both bolts tightened) into s2's
    # order, s2's into s3's
    with sqlite3.connect(tmp_path / "line.sqlite") as db:
        carried = [json.loads(c) for (c,) in db.execute("SELECT carried FROM visits WHERE step > 0")]
    assert len(carried) == 10 and all(c[bolt(1)] == c[bolt(2)] == "tightened" for c in carried), carried


def watch_the_page(said: list[str], tmp_path: Path) -> dict[str, dict[str, str]]:
    """In Chromium, the page `hubctl line up` serves (its URL as printed), until it shows s2 unreachable once
    router r2 was killed: the stations' rows then."""
    url = wait_for(lambda: next((s.split()[2] for s in said if s.startswith("overview page: http")), None), 120,
               "line up prints its overview page's URL")
    with chromium() as driver:
        driver.get(url)
        wait_for(lambda: len(station_rows(driver)) == 3, 120, "the page lists the 3 stations")
        wait_for(lambda: any("KILLED router r2" in s for s in said), 300, "router r2 killed")
        wait_for(lambda: unreachable_shown(driver, "s2"), 60, "s2 shown unreachable on the page")
        rows = station_rows(driver)
        driver.save_screenshot(str(tmp_path / "line-overview-r2-down.png"))
    return rows


@pytest.mark.slow
async def test_a_line_runs_with_tls_and_access_control_at_the_routers(tmp_path):
    """The same line with [security] mode = "tls": a throw-away site CA, every router enforcing the stations'
    and the line controller's access control; the line controller's order queries and the overview's status
    reads pass it, and the line finishes."""
    line = write_line(tmp_path, 2, tls=True)
    said: list[str] = []
    result = await run_line(LineOptions(config=str(line), products=2, run_dir=tmp_path / "run", time_limit=240,
                                        overview_every_s=5.0, overview_bind="127.0.0.1:0"), said.append)
    text = "\n".join(said)
    assert "links: mutual TLS with the site's certificates" in text
    assert result.finished, text
    assert [r.done for r in result.last_rows] == [2, 2], text
    assert all(not d.redone() for d in result.done_once.values())
