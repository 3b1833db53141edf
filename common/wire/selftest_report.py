"""A hub's self-test report, `{station}/hub/{hub}/selftest`: what the hub publishes at boot (hubs/selftest.py
runs the checks) and what `hubctl deploy`, `hubctl selftest` and the console read."""

from __future__ import annotations

import msgspec

from common.wire.messages import Message


class CheckMessage(msgspec.Struct, frozen=True):
    name: str
    ok: bool
    detail: str = ""


class DeviceReport(msgspec.Struct, frozen=True):
    resource: str
    ok: bool
    checks: list[CheckMessage]


class SelftestMessage(Message, kw_only=True):
    hub: str
    ok: bool
    devices: list[DeviceReport]
    time: float


def format_report(message: SelftestMessage) -> str:
    lines = [f"self-test of hub {message.hub}: {'PASS' if message.ok else 'FAIL'}"]
    for device in message.devices:
        lines.append(f"  {device.resource}: {'ok' if device.ok else 'FAILED'}")
        for check in device.checks:
            mark = "ok  " if check.ok else "FAIL"
            lines.append(f"    [{mark}] {check.name}" + (f": {check.detail}" if check.detail else ""))
    return "\n".join(lines)
