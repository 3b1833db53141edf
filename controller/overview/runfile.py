"""The run the overview's Gantt chart draws: the station's newest recording, read again as it grows.

The controller records every run into `[controller.recording] dir` (controller/recording/); `hubctl
timeline` draws such a recording, and so does the overview, from the same `Timeline`. The overview
therefore runs where the recordings are (the controller PC, like the console's `t`). Only runs of this
station count: the directory may hold other stations' runs (tests, several stations on one PC).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from common.model import Model
from controller.recording.reader import RecordingError, RunInfo, list_runs, open_run
from controller.timeline.model import build_timeline

from .picture import Gantt, gantt, no_gantt


def newest_run(directory: Path, station: str) -> RunInfo | None:
    runs = [r for r in list_runs(directory) if not r.problem and r.meta.station == station]
    return runs[-1] if runs else None


@dataclass
class RunGantt:
    """The Gantt data of `station`'s newest run in `directory`, built again only when its files changed."""

    directory: Path
    station: str
    model: Model
    _seen: tuple[str, int, float] | None = field(default=None, init=False)
    _gantt: Gantt | None = field(default=None, init=False)

    def read(self) -> Gantt:
        """Blocking (SQLite): run it off the event loop."""
        try:
            run = newest_run(self.directory, self.station)
        except OSError as exc:
            return no_gantt(f"recordings in {self.directory} unreadable: {exc}")
        if run is None:
            return no_gantt(f"no recorded run of station {self.station} in {self.directory.resolve()} (the Gantt "
                            f"chart needs the controller's recordings: run the overview on the controller PC)")
        stamp = self._stamp(run)
        if stamp == self._seen and self._gantt is not None:
            return self._gantt
        try:
            with open_run(run.path) as opened:
                drawn = gantt(build_timeline(opened, self.model))
        except (RecordingError, OSError) as exc:
            return no_gantt(f"run {run.path} unreadable: {exc}")
        self._seen, self._gantt = stamp, drawn
        return drawn

    @staticmethod
    def _stamp(run: RunInfo) -> tuple[str, int, float]:
        """What changes when the run's recording grows: its files' size and newest modification (WAL included)."""
        files = [p for p in run.path.parent.glob(f"{run.path.stem.split('.')[0]}*") if p.is_file()]
        return (str(run.path), sum(p.stat().st_size for p in files),
                max((p.stat().st_mtime for p in files), default=0.0))
