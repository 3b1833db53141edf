"""The station's key expressions (DESIGN.md §5): one `Keys` per station, from `station_keys()`.

    {station}/res/{resource}/cmd     controller -> hub   command (messages.Codec)
    {station}/res/{resource}/state   hub -> controller   measured state + mirror
    {station}/hub/{hub}/alive        liveliness token of a running hub
    {station}/hub/{hub}/selftest     self-test report
    {station}/ctl/status             controller -> consoles   status (what changed; a query: all of it)
    {station}/ctl/plan/{id}          queryable: a plan's steps and guards (ctl.PlanDetails)
    {station}/ctl/holder/{epoch}/{controller}/{host}/{pid}
                                     liveliness token of the controller holding the station
    {station}/ctl/...                controller: global state, console requests

Processes get their keys from `StationConfig.keys` (or `station_keys(name)` when they
know only the station's name): built once per station, never spelled out twice.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

_FORBIDDEN_IN_NAME = set("/*$?#@ ") | {"\t", "\n"}


class KeyExprError(ValueError):
    """A station, resource or hub name that cannot be one chunk of a key expression."""


def check_name(what: str, name: str) -> str:
    """A name used as one key chunk: non-empty, no '/', no wildcard or reserved character."""
    if not name or any(c in _FORBIDDEN_IN_NAME for c in name):
        raise KeyExprError(f"{what} name {name!r} cannot be used in a key expression "
                           f"(empty, or contains one of / * $ ? # @ or whitespace)")
    return name


@dataclass(frozen=True)
class Keys:
    """The key expressions of one station. Methods give concrete keys, `all_*` wildcard ones."""

    station: str

    def __post_init__(self) -> None:
        check_name("station", self.station)

    # resources
    def cmd(self, resource: str) -> str:
        return f"{self.station}/res/{check_name('resource', resource)}/cmd"

    def state(self, resource: str) -> str:
        return f"{self.station}/res/{check_name('resource', resource)}/state"

    @property
    def all_cmd(self) -> str:
        return f"{self.station}/res/*/cmd"

    @property
    def all_state(self) -> str:
        return f"{self.station}/res/*/state"

    # hubs
    def alive(self, hub: str) -> str:
        return f"{self.station}/hub/{check_name('hub', hub)}/alive"

    def selftest(self, hub: str) -> str:
        return f"{self.station}/hub/{check_name('hub', hub)}/selftest"

    @property
    def all_alive(self) -> str:
        return f"{self.station}/hub/*/alive"

    def call(self, hub: str, resource: str) -> str:
        """The liveliness token of an operator's call for the supervisor, alive while the call stands."""
        return f"{self.station}/hub/{check_name('hub', hub)}/call/{check_name('resource', resource)}"

    @property
    def all_calls(self) -> str:
        return f"{self.station}/hub/*/call/*"

    def call_of(self, key: str) -> tuple[str, str] | None:
        """(`human`, `human`) for `station/hub/human/call/human`, else None."""
        parts = key.split("/")
        if len(parts) == 5 and parts[0] == self.station and parts[1] == "hub" and parts[3] == "call":
            return parts[2], parts[4]
        return None

    @property
    def all_selftest(self) -> str:
        return f"{self.station}/hub/*/selftest"

    # controller
    def ctl(self, *parts: str) -> str:
        """`{station}/ctl/a/b` for ctl("a", "b"); parts may hold '/' (e.g. "console/request")."""
        if not parts or any(not p or p.startswith("/") or p.endswith("/") for p in parts):
            raise KeyExprError(f"bad ctl key parts {parts!r}")
        return "/".join((self.station, "ctl", *parts))

    def plan(self, plan_id: int) -> str:
        """The queryable of the plan `plan_id` (its steps, guards and what its pending steps wait for)."""
        return self.ctl("plan", str(plan_id))

    @property
    def all_plans(self) -> str:
        return self.ctl("plan", "*")

    def plan_of(self, key: str) -> int | None:
        """7 for `station/ctl/plan/7`, else None."""
        prefix = self.ctl("plan") + "/"
        rest = key[len(prefix):] if key.startswith(prefix) else ""
        return int(rest) if rest.isdigit() else None

    def holder(self, epoch: int, controller: str, host: str, pid: int) -> str:
        """The liveliness token of the controller holding the station (common/wire/holder_token.py)."""
        return self.ctl("holder", str(epoch), check_name("controller", controller), check_name("host", host), str(pid))

    @property
    def all_holders(self) -> str:
        return f"{self.station}/ctl/holder/**"

    # parsing
    def resource_of(self, key: str) -> str | None:
        """`nr` for `station/res/nr/state` (or `/cmd`), else None."""
        parts = key.split("/")
        if len(parts) == 4 and parts[0] == self.station and parts[1] == "res" and parts[3] in ("cmd", "state"):
            return parts[2]
        return None

    def hub_of(self, key: str) -> str | None:
        """`pi-tool` for `station/hub/pi-tool/alive` (or `/selftest`), else None."""
        parts = key.split("/")
        if len(parts) == 4 and parts[0] == self.station and parts[1] == "hub":
            return parts[2]
        return None


@functools.cache
def station_keys(station: str) -> Keys:
    """The keys of `station` (checked once, shared by everything in the process that talks to it)."""
    return Keys(station)
