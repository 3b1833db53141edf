"""Boot self-test: every device answers, inputs read, outputs read back; one report per hub.

The hub publishes the report at start (and answers queries for it); `hubctl selftest
HUB` runs the same checks without the bus, prints them and exits non-zero on a
failure so that systemd refuses to start a broken hub. The report itself: common/wire/selftest_report.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterable, Mapping

from common.wire.selftest_report import CheckMessage, DeviceReport, SelftestMessage

from .drivers.base import Driver, SelftestReport


def report_message(hub: str, reports: Iterable[SelftestReport]) -> SelftestMessage:
    devices = [DeviceReport(r.resource, r.ok, [CheckMessage(c.name, c.ok, c.detail) for c in r.checks])
               for r in reports]
    return SelftestMessage(hub=hub, ok=all(d.ok for d in devices), devices=devices, time=time.time())


async def run_selftest(hub: str, drivers: Mapping[str, Driver], connect_timeout: float = 3.0) -> SelftestMessage:
    for driver in drivers.values():
        await driver.connect()
    deadline = time.monotonic() + connect_timeout
    while time.monotonic() < deadline and not all(d.connected for d in drivers.values()):
        await asyncio.sleep(0.05)
    reports = []
    for name, driver in drivers.items():
        try:
            reports.append(await driver.selftest())
        except Exception as exc:
            failed = SelftestReport(name)
            failed.add("self-test ran", False, f"{type(exc).__name__}: {exc}")
            reports.append(failed)
    for driver in drivers.values():
        with contextlib.suppress(Exception):  # closing a broken device must not hide the report
            await driver.close()
    return report_message(hub, reports)
