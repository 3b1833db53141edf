"""A small station of the test line: the fault station's robot and nutrunner, two bolts, and the bolts
as the product's variables, so that each order starts from placed bolts and archives them tightened."""

from __future__ import annotations

from common.model import Model
from tests.fault_station.model import bolt, bolt_station

BOLTS = (1, 2)

__all__ = ["BOLTS", "bolt", "build_model"]


def build_model() -> Model:
    return bolt_station("line_station", BOLTS, product=("engine.*",))
