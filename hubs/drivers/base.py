"""The one driver interface every device implementation satisfies (emulate, sim and real alike).

The hub runtime holds a `Driver` per resource and never knows which kind it holds:
it calls `connect` once, then `read` at its rate, `write` when a command arrives, and
`enter_safe_state` at hub start and when commands stop arriving. Values are keyed by
the variable's short name (`run_m`, not `nr.run_m`), and use the model's domains
(bools, enumeration names, small ints).

Optional capabilities are declared by inheriting them, never probed for:

* `Inputs`: the driver's device depends on variables of other resources (an emulated
  tool changer sees where the robot is); the runtime subscribes to them and hands
  their values to `Observes.observe`.
* `Observes`: the driver takes values of other resources' variables.
* `CallsSupervisor`: a person at the device can call the supervisor (the operator's page); the hub
  holds a liveliness token while the call stands, and the controller logs it.
* `InStation`: the driver needs the station around its device (the model, hubs.toml, its hub): the
  factory hands it over once built (the operator's page reads the model's confirm conditions).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from common.model import Value

if TYPE_CHECKING:
    from common.config.hubs_toml import StationConfig
    from common.model import Model


class DeviceUnavailable(Exception):
    """The device does not answer (disconnected, timed out, protocol error)."""


@dataclass
class CheckResult:
    name: str  # "device answers", "inputs read", "outputs read back", ...
    ok: bool
    detail: str = ""


@dataclass
class SelftestReport:
    resource: str
    checks: list[CheckResult] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    def add(self, name: str, ok: bool, detail: str = "") -> None:
        self.checks.append(CheckResult(name, ok, detail))


class Driver(abc.ABC):
    """A device behind a resource. Implementations must never block the event loop."""

    resource: str  # the resource name in the model, e.g. "nr"

    @abc.abstractmethod
    async def connect(self) -> None:
        """Start talking to the device; returns at once and keeps (re)connecting in the background."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Stop background work and release the device."""

    @property
    @abc.abstractmethod
    def connected(self) -> bool:
        """True while the device answers; stale values are never reported as fresh."""

    @abc.abstractmethod
    async def read(self) -> Mapping[str, Value]:
        """The measured variables now. Raises DeviceUnavailable when the device does not answer."""

    @abc.abstractmethod
    async def write(self, commands: Mapping[str, Value]) -> None:
        """Drive the outputs to the command variables. Raises DeviceUnavailable when it cannot."""

    @abc.abstractmethod
    async def enter_safe_state(self) -> Mapping[str, Value]:
        """Stop any motion under way and drive the outputs to their safe values; return the command
        values now applied. The hub mirrors exactly these; a variable left out keeps its value (a tool
        changer never drops its tool, a robot holds its reference but stands still) and nothing is
        written afterwards: the next command the hub receives is applied as usual, motion included.
        Raises DeviceUnavailable when the device does not answer (the driver still remembers the
        safe values and drives them when the device returns)."""

    @abc.abstractmethod
    async def selftest(self) -> SelftestReport:
        """Device answers, inputs read, outputs read back where the device allows."""


class NoOutputs:
    """Mixed into the driver of a device with no command variables (a camera, a badge reader):
    nothing to write and no safe state to enter."""

    async def write(self, commands: Mapping[str, Value]) -> None:
        return None

    async def enter_safe_state(self) -> Mapping[str, Value]:
        return {}


class Inputs(abc.ABC):
    """Declared capability: the device depends on variables of other resources."""

    @property
    @abc.abstractmethod
    def inputs(self) -> tuple[str, ...]:
        """Full variable paths (`ur.pos_m`) of other resources whose values this driver needs."""


class Observes(abc.ABC):
    """Declared capability: the driver takes values of other resources' variables."""

    @abc.abstractmethod
    def observe(self, values: Mapping[str, Value], published_at: float | None = None) -> None:
        """New values, keyed by full variable path; may hold paths the driver did not ask for.

        `published_at`: when their publisher sent them (its wall clock, s since the epoch), or
        None when unknown."""


@dataclass(frozen=True)
class StationContext:
    model: Model
    config: StationConfig
    hub: str
    certs: str | None = None  # the certificate directory given on the command line (`--certs`)


class InStation(abc.ABC):
    """Declared capability: the driver is told the station it serves before the hub connects it."""

    @abc.abstractmethod
    def join_station(self, station: StationContext) -> None:
        """The station's model, hubs.toml and this hub's name. Raises ValueError when the driver cannot
        serve its resource in this station (named in the message)."""


class CallsSupervisor(abc.ABC):
    """Declared capability: a person at the device can call the supervisor."""

    @abc.abstractmethod
    async def next_call(self) -> bool:
        """Wait until the call for the supervisor begins (True) or ends (False)."""
