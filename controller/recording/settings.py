"""`[controller.recording]` of hubs.toml (checked key by key by common/config/hubs_toml.py)."""

from __future__ import annotations

from typing import Annotated

import msgspec


class RecordingConfig(msgspec.Struct, frozen=True):
    dir: Annotated[str, msgspec.Meta(min_length=1)] = "var/runs"  # one SQLite file per run, relative to the cwd
    max_mb: Annotated[float, msgspec.Meta(gt=0)] = 200.0  # a run goes on in a next part file beyond this size
    keep: Annotated[int, msgspec.Meta(ge=1)] = 50  # recording files kept in dir: the oldest are deleted
