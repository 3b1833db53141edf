"""The errors of a deployment file (hubs.toml): every problem with its file, line and key."""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class ConfigProblem:
    file: str
    line: int | None
    key: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        return f"{where}: {self.key}: {self.message}" if self.key else f"{where}: {self.message}"


class ConfigError(ValueError):
    """One or more problems in a deployment file, each with file, line and key."""

    def __init__(self, problems: list[ConfigProblem]) -> None:
        self.problems = problems
        if len(problems) == 1:
            text = str(problems[0])
        else:
            text = f"{len(problems)} problems:\n" + "\n".join(f"  {p}" for p in problems)
        super().__init__(text)

    @property
    def line(self) -> int | None:
        return self.problems[0].line

    @property
    def key(self) -> str:
        return self.problems[0].key


def toml_type(value: object) -> str:
    """How a TOML value's type reads in an error: 'an integer', 'a table'."""
    return {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "an array",
            dict: "a table"}.get(type(value), type(value).__name__)


def toml_problem(file: str, message: str) -> ConfigProblem:
    """A tomllib error as a problem with its line, and the two common mistakes said plainly."""
    match = re.match(r"(?P<msg>.*) \(at line (?P<line>\d+), column \d+\)$", message)
    if not match:
        return ConfigProblem(file, None, "", f"invalid TOML: {message}")
    text, line = match.group("msg"), int(match.group("line"))
    declared = re.match(r"Cannot declare \((?P<keys>.*)\) twice", text)
    if declared:
        keys = tuple(re.findall(r"'((?:[^'\\]|\\.)*)'", declared.group("keys")))
        key = ".".join(keys)
        if len(keys) == 2 and keys[0] == "hubs":
            return ConfigProblem(file, line, key, f"duplicate hub name {keys[1]!r} (its table is declared twice)")
        return ConfigProblem(file, line, key, "table declared twice")
    if text == "Cannot overwrite a value":
        return ConfigProblem(file, line, "", "a key is set twice (or a table overwrites a value)")
    return ConfigProblem(file, line, "", f"invalid TOML: {text}")
