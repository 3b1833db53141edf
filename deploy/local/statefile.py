"""Reading a station state from TOML (`hubctl plan --from STATE.toml`), with errors naming the key."""

from __future__ import annotations

import tomllib
from pathlib import Path

from common.model import Model, Value


class StateFileError(ValueError):
    pass


def _flatten(table: dict, prefix: str = "") -> dict[str, object]:
    flat: dict[str, object] = {}
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            flat.update(_flatten(value, path))
        else:
            flat[path] = value
    return flat


def _line_of(text: str, key: str) -> int | None:
    leaf = key.rsplit(".", 1)[-1]
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip().strip('"')
        if stripped.startswith((key, f'"{key}"', leaf)):
            return number
    return None


def load_state(path: str | Path, model: Model) -> dict[str, Value]:
    """Values by variable path: `"ur.pos_m" = "home"` or `[ur]` tables with `pos_m = "home"`."""
    file = Path(path)
    try:
        text = file.read_text()
    except OSError as exc:
        raise StateFileError(f"{file}: cannot read: {exc.strerror}") from exc
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise StateFileError(f"{file}: {exc}") from exc
    values: dict[str, Value] = {}
    problems = []
    for key, value in _flatten(table).items():
        where = f"{file}:{_line_of(text, key) or '?'}: key {key!r}"
        var = model.variables.get(key)
        if var is None:
            problems.append(f"{where}: no such variable in model {model.name!r}")
            continue
        if value not in var.domain:
            problems.append(f"{where}: {value!r} is outside the domain of {key} ({var.domain.describe()})")
            continue
        values[key] = value  # type: ignore[assignment]  # checked against the domain above
    if problems:
        raise StateFileError("\n".join(problems))
    return values
