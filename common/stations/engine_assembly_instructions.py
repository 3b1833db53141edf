"""The operator's work instructions of the reference station (common/stations/engine_assembly.py), in
English and Swedish, with a picture each (engine_assembly_pictures/)."""

from __future__ import annotations

from pathlib import Path

from .engine_assembly import (
    FILTERS,
    LIFT_FRAME,
    MOUNT_FILTER_TASKS,
    MOUNT_OIL_PIPES,
    PIPES,
    PLACE_BOLTS,
    TIGHTEN_PIPE_TASKS,
)
from .instructions import Instruction, InstructionTable

PICTURES = Path(__file__).with_name("engine_assembly_pictures")

INSTRUCTIONS = InstructionTable(
    steps=(
        Instruction(LIFT_FRAME, {
            "en": "Guide the ladder frame with the robot onto the engine and check that it is seated.",
            "sv": "Styr stegramen med roboten ner på motorn och kontrollera att den sitter.",
        }, PICTURES / "frame.svg"),
        Instruction(PLACE_BOLTS, {
            "en": "Place the 24 frame bolts in their holes, hand-tight.",
            "sv": "Sätt de 24 ramskruvarna i sina hål, handåtdragna.",
        }, PICTURES / "bolts.svg"),
        *(Instruction(task, {
            "en": f"Mount oil filter {k} by hand.",
            "sv": f"Montera oljefilter {k} för hand.",
        }, PICTURES / "filter.svg") for k, task in zip(FILTERS, MOUNT_FILTER_TASKS, strict=True)),
        Instruction(MOUNT_OIL_PIPES, {
            "en": "Mount both oil pipes with their plates.",
            "sv": "Montera båda oljerören med sina plattor.",
        }, PICTURES / "pipes.svg"),
        *(Instruction(task, {
            "en": f"Take the nutrunner from the dock and tighten the plate of oil pipe {k}. "
                  "You are in the robot's zone: the robot waits.",
            "sv": f"Ta mutterdragaren från dockan och dra plattan till oljerör {k}. "
                  "Du är i robotens zon: roboten väntar.",
        }, PICTURES / "pipes.svg") for k, task in zip(PIPES, TIGHTEN_PIPE_TASKS, strict=True)),
    ),
    languages=("en", "sv"),
)
