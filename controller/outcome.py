"""How a run ended."""

from __future__ import annotations

from enum import StrEnum


class RunOutcome(StrEnum):
    FINISHED = "finished"  # every operation finished
    STOPPED = "stopped"  # asked to stop (the controller's SIGTERM, a console's Ctrl-C)
    STUCK = "stuck"  # in virtual time: nothing can happen any more, and not every operation finished
    TIME_LIMIT = "time-limit"  # in virtual time: the run's time limit came first

    @property
    def recorded(self) -> str:
        """As a recording's meta says it (`hubctl runs`): a run ended by its time limit was stopped, the
        note says why."""
        return RunOutcome.STOPPED.value if self is RunOutcome.TIME_LIMIT else self.value
