"""The operator station's work instructions."""

from __future__ import annotations

from common.stations.instructions import Instruction, InstructionTable

INSTRUCTIONS = InstructionTable(steps=(
    Instruction("fit_part", {"en": "Fit the part the robot holds.", "sv": "Passa in delen som roboten håller."}),
))
