"""The emulated driver: effects that read other resources wait for news of them after a command."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Awaitable, Callable

import pytest

from common.model import Value
from common.stations.engine_assembly import build_model
from hubs.drivers.emulated import EmulatedDriver
from tests.drivers.drvtest import read_until

MODEL = build_model()
FAST = 1000.0  # effects take 0.15 ms: any lag of the robot's news would be taken as news

Start = Callable[..., Awaitable[EmulatedDriver]]


@pytest.fixture
async def emulated() -> AsyncIterator[Start]:
    """Start emulated drivers of the reference model's resources; each is closed after the test."""
    started: list[EmulatedDriver] = []

    async def start(resource: str, input_wait: float) -> EmulatedDriver:
        driver = EmulatedDriver(MODEL, resource, speed=FAST, input_wait=input_wait)
        started.append(driver)
        await driver.connect()
        return driver

    yield start
    for driver in started:
        await driver.close()


class Neighbours:
    """What the other hubs publish at their rate, handed to the tool changer: every input it reads."""

    def __init__(self, driver: EmulatedDriver) -> None:
        self.driver = driver
        self.values: dict[str, Value] = {"ur.pos_m": "dock_filter_tool", "dock.nutrunner_home_m": True,
                                         "dock.lift_tool_home_m": True, "dock.filter_tool_home_m": True}

    def news(self, published_at: float | None = None, **changes: Value) -> None:
        """Every input, stamped now (or `published_at`), with `changes` (`ur__pos_m` for `ur.pos_m`)."""
        self.values.update({path.replace("__", "."): value for path, value in changes.items()})
        self.driver.observe(dict(self.values), time.time() if published_at is None else published_at)

    async def hold_the_filter_tool(self) -> None:
        self.news(ur__pos_m="dock_filter_tool", dock__filter_tool_home_m=True)
        await self.driver.write({"lock_c": True})
        self.news()
        await read_until(self.driver, locked_m=True, tool_m="filter_tool")
        self.news(ur__pos_m="unknown", dock__filter_tool_home_m=False)


async def test_an_unlock_waits_for_the_robots_news_published_after_the_command(emulated: Start) -> None:
    """The controller saw the robot at the dock and commanded unlock; this hub's news of the robot is
    older (still on its way). Fired on that, the unlock would keep the tool on the plate: a dead end."""
    changer = await emulated("rsp", input_wait=2.0)
    neighbours = Neighbours(changer)
    await neighbours.hold_the_filter_tool()
    seen_on_the_way = time.time()
    await asyncio.sleep(0.01)
    await changer.write({"lock_c": False})  # came before the robot's news
    neighbours.news(seen_on_the_way)  # old news (the robot on its way), overtaken by the command
    await asyncio.sleep(0.05)  # 300 effect delays
    assert dict(await changer.read())["tool_m"] == "filter_tool"  # not fired on old news ...
    neighbours.news(ur__pos_m="dock_filter_tool")  # ... the robot's news comes
    await read_until(changer, locked_m=False, tool_m="none")  # put down in its slot


async def test_news_that_the_robot_is_away_still_unlocks_without_releasing(emulated: Start) -> None:
    """The wait changes when an effect fires, not which: fresh news of the robot away from the dock
    unlocks with the tool still coupled (the state the model forbids and the controller never asks)."""
    changer = await emulated("rsp", input_wait=2.0)
    neighbours = Neighbours(changer)
    await neighbours.hold_the_filter_tool()
    await changer.write({"lock_c": False})
    neighbours.news(ur__pos_m="above_engine")
    await read_until(changer, locked_m=False, tool_m="filter_tool")


async def test_a_silent_input_holds_an_effect_at_most_input_wait(emulated: Start) -> None:
    changer = await emulated("rsp", input_wait=0.2)
    await Neighbours(changer).hold_the_filter_tool()
    started = time.monotonic()
    await changer.write({"lock_c": False})  # no news of the robot from here on
    await read_until(changer, locked_m=False)
    assert time.monotonic() - started >= 0.2


async def test_effects_on_own_variables_only_do_not_wait(emulated: Start) -> None:
    """A nutrunner's effects read nothing of other resources: they fire after their delay alone."""
    nutrunner = await emulated("nr", input_wait=5.0)
    await nutrunner.write({"run_c": True})
    await read_until(nutrunner, timeout=1.0, run_m=True)


async def test_inputs_never_heard_of_are_not_waited_for(emulated: Start) -> None:
    """Tested alone (`hubctl test`, the robot's hub not running): the model's initial values are all
    there will be, so nothing waits for news that cannot come."""
    changer = await emulated("rsp", input_wait=5.0)
    await changer.write({"lock_c": True})  # the robot at home (its initial pose): locks on nothing
    await read_until(changer, timeout=1.0, locked_m=True, tool_m="none")
