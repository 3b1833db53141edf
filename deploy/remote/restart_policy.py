"""How a station process is restarted when it exits: what the systemd units say, and what `hubctl up` does.

One description, two readers: deploy/remote/units.py renders it as unit lines (`Restart=`,
`RestartSec=`, `RestartSteps=`, `RestartMaxDelaySec=`, `StartLimitIntervalSec=`,
`StartLimitBurst=`) and deploy/local/supervisor.py follows it as systemd would, so that a
`hubctl up` on one machine restarts its processes the way the cell does.

The units never give up (`StartLimitIntervalSec=0`, deploy/remote/units.py says why: a unit
that gave up would need a person at the ECU). `hubctl up` is a run with an end and a person
watching it, so it adds a start limit to the cell's policy: a process that keeps dying ends
the run with the reason instead of retrying (at 60 s a try) until the run's time limit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


def _seconds(value: float) -> str:
    """A systemd time span: 5 -> '5s', 0.5 -> '500ms'."""
    return f"{value:g}s" if float(value).is_integer() else f"{round(value * 1000)}ms"


@dataclass(frozen=True)
class StartLimit:
    """More than `burst` starts within `interval_s` (systemd's window, begun by its first start) is refused."""

    interval_s: float
    burst: int


@dataclass(frozen=True)
class RestartPolicy:
    """`Restart=always`: the process is restarted whatever its exit, after `delay_s`, a delay that grows over
    `steps` restarts up to `max_delay_s` (systemd's RestartSteps; 0: always `delay_s`)."""

    delay_s: float
    steps: int = 0
    max_delay_s: float | None = None
    start_limit: StartLimit | None = None  # None: StartLimitIntervalSec=0, no limit

    def delay(self, restart: int) -> float:
        """The delay before restart number `restart` (1 = the first), as systemd 254+ computes it: RestartSec,
        then growing geometrically so that the `steps`-th restart waits RestartMaxDelaySec, and every later one."""
        if self.steps == 0 or self.max_delay_s is None or self.delay_s <= 0 or self.delay_s >= self.max_delay_s \
                or restart <= 1:
            return self.delay_s
        if restart > self.steps:
            return self.max_delay_s
        return self.delay_s * (self.max_delay_s / self.delay_s) ** ((restart - 1) / self.steps)

    def unit_lines(self) -> list[str]:
        """Its [Unit] section lines (the start limit)."""
        if self.start_limit is None:
            return ["StartLimitIntervalSec=0"]
        limit = self.start_limit
        return [f"StartLimitIntervalSec={_seconds(limit.interval_s)}", f"StartLimitBurst={limit.burst}"]

    def service_lines(self) -> list[str]:
        """Its [Service] section lines (what to restart and when)."""
        lines = ["Restart=always", f"RestartSec={_seconds(self.delay_s)}"]
        if self.steps and self.max_delay_s is not None:
            lines += [f"RestartSteps={self.steps}", f"RestartMaxDelaySec={_seconds(self.max_delay_s)}"]
        return lines


# The cell's units: from systemd 254 on a delay growing from 1 s to 60 s; older systemd (Debian and Raspberry Pi OS
# bookworm ship 252) has no RestartSteps, hence a fixed 5 s.
GROWING_RESTART = RestartPolicy(delay_s=1.0, steps=6, max_delay_s=60.0)
FIXED_RESTART = RestartPolicy(delay_s=5.0)
# `hubctl up`: the cell's growing delay, plus a start limit. A process dying at once reaches its 6th start ~30 s
# after its first (delays 1, 2, 3.9, 7.7, 15.3 s) plus its start-up times, well within 120 s; a chaos run kills a
# process at most a few times (deploy/local/chaos.py), far below 5 starts.
UP_RESTART = replace(GROWING_RESTART, start_limit=StartLimit(interval_s=120.0, burst=5))


def unit_restart_policy(systemd_version: int, backoff_from: int) -> RestartPolicy:
    """The units' policy for a target with `systemd_version` (a growing delay needs `backoff_from` or newer)."""
    return GROWING_RESTART if systemd_version >= backoff_from else FIXED_RESTART
