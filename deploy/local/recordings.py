"""Where `hubctl up` records its run, and finding that recording again when the run ends."""

from __future__ import annotations

from pathlib import Path

from common.config.hubs_toml import RecordingConfig, load_config
from common.model import Model
from controller.planner import Budget
from controller.recording.hooks import open_recording
from controller.recording.reader import list_runs
from controller.recording.schema import BudgetCounts, RunMeta, RunMode
from controller.recording.writer import RecordingWriter, recording_dir


def recording_settings(config_path: str | Path | None) -> RecordingConfig:
    """`[controller.recording]` of the station's hubs.toml, or the defaults without one."""
    if config_path is None or not Path(config_path).is_file():
        return RecordingConfig()
    return load_config(config_path).controller.recording


def in_process_recording(model: Model, model_reference: str, config_path: str | None, *, seed: int,
                         budget: Budget) -> RecordingWriter | None:
    """The recording of an `up --in-process` run: its planner counts are in it, so a replay plans alike."""
    counts = BudgetCounts(first_expansions=budget.first_expansions, improve_expansions=budget.improve_expansions,
                          symbolic_layers=budget.symbolic_layers)
    meta = RunMeta(station=model.name, model=model_reference, config=config_path or "", mode=RunMode.IN_PROCESS,
                   seed=seed,
                   budget=counts)
    return open_recording(recording_settings(config_path), meta, model)


def recording_since(config_path: str, started: float) -> Path | None:
    """The newest recording in the station's recording dir begun at or after `started` (wall clock)."""
    directory = recording_dir(recording_settings(config_path).dir)
    runs = [r for r in list_runs(directory) if not r.problem and r.meta.started >= started]
    return runs[-1].path if runs else None
