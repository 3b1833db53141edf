"""The emulated driver: effects that read other resources wait for news of them after a command."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import pytest

from common.stations.engine_assembly import build_model
from hubs.drivers.emulated import EmulatedDriver

MODEL = build_model()
FAST = 1000.0  # effects take 0.15 ms: any lag of the robot's news would be taken as news


@pytest.fixture
async def changer() -> AsyncIterator[EmulatedDriver]:
    driver = EmulatedDriver(MODEL, "rsp", speed=FAST, input_wait=2.0)
    await driver.connect()
    try:
        yield driver
    finally:
        await driver.close()


async def until(driver: EmulatedDriver, timeout: float = 2.0, **wanted: object) -> None:
    deadline = time.monotonic() + timeout
    while (values := await driver.read()) and any(values[k] != v for k, v in wanted.items()):
        assert time.monotonic() < deadline, f"{driver.resource}: {values}, wanted {wanted}"
        await asyncio.sleep(0.005)


WORLD = {"ur.pos_m": "dock_filter_tool", "dock.nutrunner_home_m": True, "dock.lift_tool_home_m": True,
         "dock.filter_tool_home_m": True}


def news(driver: EmulatedDriver, published_at: float | None = None, **changes: object) -> None:
    """What the other hubs publish at their rate: every input, stamped now (or `published_at`)."""
    WORLD.update({path.replace("__", "."): value for path, value in changes.items()})
    driver.observe(dict(WORLD), time.time() if published_at is None else published_at)  # type: ignore[arg-type]


async def hold_the_filter_tool(driver: EmulatedDriver) -> None:
    news(driver, ur__pos_m="dock_filter_tool", dock__filter_tool_home_m=True)
    await driver.write({"lock_c": True})
    news(driver)
    await until(driver, locked_m=True, tool_m="filter_tool")
    news(driver, ur__pos_m="unknown", dock__filter_tool_home_m=False)


async def test_an_unlock_waits_for_the_robots_news_published_after_the_command(changer: EmulatedDriver) -> None:
    """The controller saw the robot at the dock and commanded unlock; this hub's news of the robot is
    older (still on its way). Fired on that, the unlock would keep the tool on the plate: a dead end."""
    await hold_the_filter_tool(changer)
    seen_on_the_way = time.time()
    await asyncio.sleep(0.01)
    await changer.write({"lock_c": False})  # came before the robot's news
    news(changer, seen_on_the_way)  # old news (the robot on its way), overtaken by the command
    await asyncio.sleep(0.05)  # 300 effect delays
    assert dict(await changer.read())["tool_m"] == "filter_tool"  # not fired on old news ...
    news(changer, ur__pos_m="dock_filter_tool")  # ... the robot's news comes
    await until(changer, locked_m=False, tool_m="none")  # put down in its slot


async def test_news_that_the_robot_is_away_still_unlocks_without_releasing(changer: EmulatedDriver) -> None:
    """The wait changes when an effect fires, not which: fresh news of the robot away from the dock
    unlocks with the tool still coupled (the state the model forbids and the controller never asks)."""
    await hold_the_filter_tool(changer)
    await changer.write({"lock_c": False})
    news(changer, ur__pos_m="above_engine")
    await until(changer, locked_m=False, tool_m="filter_tool")


async def test_a_silent_input_holds_an_effect_at_most_input_wait() -> None:
    driver = EmulatedDriver(MODEL, "rsp", speed=FAST, input_wait=0.2)
    await driver.connect()
    try:
        await hold_the_filter_tool(driver)
        started = time.monotonic()
        await driver.write({"lock_c": False})  # no news of the robot from here on
        await until(driver, locked_m=False)
        assert time.monotonic() - started >= 0.2
    finally:
        await driver.close()


async def test_effects_on_own_variables_only_do_not_wait() -> None:
    """A nutrunner's effects read nothing of other resources: they fire after their delay alone."""
    driver = EmulatedDriver(MODEL, "nr", speed=FAST, input_wait=5.0)
    await driver.connect()
    try:
        await driver.write({"run_c": True})
        await until(driver, timeout=1.0, run_m=True)
    finally:
        await driver.close()


async def test_inputs_never_heard_of_are_not_waited_for() -> None:
    """Tested alone (`hubctl test`, the robot's hub not running): the model's initial values are all
    there will be, so nothing waits for news that cannot come."""
    driver = EmulatedDriver(MODEL, "rsp", speed=FAST, input_wait=5.0)
    await driver.connect()
    try:
        await driver.write({"lock_c": True})  # the robot at home (its initial pose): locks on nothing
        await until(driver, timeout=1.0, locked_m=True, tool_m="none")
    finally:
        await driver.close()
