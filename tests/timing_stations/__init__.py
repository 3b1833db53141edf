"""Stations whose devices' timing matters: a plan is only as good as the devices' ability to follow it."""

from __future__ import annotations

from pathlib import Path

import pytest

from controller.recording.writer import RECORDING_DIR_ENV
from deploy.local.station import Options, run_station

ROOT = Path(__file__).resolve().parents[2]


async def up(config: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, time_limit: float) -> list[str]:
    """`hubctl up --config CONFIG` from the repository, its logs in `tmp_path` and its recording in `tmp_path/runs`:
    the lines it printed, once it ended with status 0."""
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))
    lines: list[str] = []
    code = await run_station(Options(config=str(config), speed=1.0, run_dir=tmp_path, time_limit=time_limit),
                             say=lines.append)
    assert code == 0, "\n".join(lines)[-3000:]
    return lines
