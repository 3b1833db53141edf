"""Work instructions for the operator's page: per task of an operator resource, its text (in one or more
languages) and a picture, from the station package.

A station names its table in the operator device's `instructions` parameter of hubs.toml as
`module:ATTRIBUTE` (`common.stations.engine_assembly_instructions:INSTRUCTIONS`); the table's order is the
order of the steps ("step n of m")."""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Instruction:
    task: str  # the operator model's task (a value of `instr_c`)
    text: dict[str, str]  # language code -> the instruction; the first is the default language
    picture: Path | None = None  # an image file (SVG, PNG, JPEG) shown beside the text

    def __post_init__(self) -> None:
        if not self.text:
            raise ValueError(f"instruction {self.task!r} has no text")

    def text_in(self, language: str) -> str:
        return self.text.get(language) or next(iter(self.text.values()))


@dataclass(frozen=True)
class InstructionTable:
    steps: tuple[Instruction, ...]
    languages: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        tasks = [step.task for step in self.steps]
        if len(set(tasks)) != len(tasks):
            raise ValueError(f"instruction table names a task twice: {tasks}")

    def step_of(self, task: str) -> tuple[int, Instruction] | None:
        """The 1-based step number of `task` and its instruction, None when the table has no such task."""
        for number, step in enumerate(self.steps, start=1):
            if step.task == task:
                return number, step
        return None

    def missing(self, tasks: tuple[str, ...]) -> list[str]:
        """The operator model's tasks that the table gives no instruction for."""
        return [task for task in tasks if self.step_of(task) is None]


def load_instructions(reference: str) -> InstructionTable:
    """The table `module:ATTRIBUTE`. Raises ValueError naming what is wrong."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"instructions {reference!r}: expected 'module:ATTRIBUTE'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f"instructions {reference!r}: cannot import {module_name}: {exc}") from exc
    table = getattr(module, attribute, None)
    if not isinstance(table, InstructionTable):
        raise ValueError(f"instructions {reference!r}: {module_name} has no InstructionTable named {attribute}")
    return table
