"""How a hub ends: on SIGTERM/SIGINT or when one of its tasks crashes, every driver enters its
safe state before the process exits, bounded in time (a device that does not answer cannot
hold the exit up: systemd would kill the process anyway, with the outputs as they were).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Sequence

from .drivers.base import DeviceUnavailable, Driver

log = logging.getLogger("statehub.hub")

SAFE_STATE_ON_EXIT_S = 3.0  # within systemd's stop timeout (90 s) and the test harness's grace (10 s)


async def wait_for_stop_or_crash(stop: asyncio.Event, tasks: Sequence[asyncio.Task[None]]) -> None:
    """Return when `stop` is set; raise the exception of the first task that fails. A task that
    ends without an error (a self-test that reported) is no crash."""
    stopped = asyncio.create_task(stop.wait(), name="stop")
    pending: set[asyncio.Task[object]] = {stopped, *tasks}
    try:
        while stopped in pending:
            done, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                error = None if task is stopped or task.cancelled() else task.exception()
                if error is not None:
                    log.error("hub task %s crashed", task.get_name())
                    raise error
    finally:
        stopped.cancel()


async def _each_within(drivers: Sequence[Driver], one: Callable[[Driver], Awaitable[None]], timeout: float) -> bool:
    """`one(driver)` for every driver, all at once; False when they did not all end within `timeout` s."""
    try:
        async with asyncio.timeout(timeout):
            await asyncio.gather(*(one(d) for d in drivers))
    except TimeoutError:
        return False
    return True


async def safe_state_on_exit(hub: str, drivers: Sequence[Driver], timeout: float = SAFE_STATE_ON_EXIT_S) -> None:
    """Every driver's `enter_safe_state`, all at once, for at most `timeout` seconds; failures are
    logged (the others still run)."""
    async def one(driver: Driver) -> None:
        try:
            await driver.enter_safe_state()
        except DeviceUnavailable as exc:
            log.error("hub %s: %s did not answer on exit; its outputs may not be safe: %s", hub, driver.resource, exc)
        except Exception:
            log.exception("hub %s: could not drive the safe state of %s on exit", hub, driver.resource)

    if await _each_within(drivers, one, timeout):
        log.info("hub %s: every output in its safe state on exit", hub)
    else:
        log.error("hub %s: the safe state on exit took more than %.1f s; exiting anyway", hub, timeout)


async def close_drivers(drivers: Sequence[Driver], timeout: float) -> None:
    """Every driver's `close`, all at once, for at most `timeout` seconds; failures are logged at debug
    level (the outputs are already safe: a connection that does not close cleanly changes nothing)."""
    async def one(driver: Driver) -> None:
        try:
            await driver.close()
        except Exception as exc:
            log.debug("%s: close failed: %s", driver.resource, exc)

    if not await _each_within(drivers, one, timeout):
        log.warning("the drivers' connections did not all close within %.1f s; exiting anyway", timeout)
