"""A station for the operator page's end-to-end test: a robot brings a part, the operator fits it and
confirms on the page. The confirmation is possible only once the robot stands at the part."""

from __future__ import annotations

from common.model import Domain, Model, estimated, operation
from common.resources import operator, ur

HOME, AT_PART = "home", "at_part"
PART = "cell.part_e"


def build_model() -> Model:
    return Model(
        "operator_station",
        (ur("ur", (HOME, AT_PART), ((HOME, AT_PART),), HOME),
         operator("human", ("fit_part",), confirm_when={"fit_part": f"ur.pos_m == {AT_PART}"},
                  on_confirm={"fit_part": f"{PART} := fitted"})),
        estimated=(estimated(PART, Domain.enum("loose", "fitted"), "loose", "the part the operator fits"),),
        operations=(operation("FitPart", f"{PART} == loose", f"{PART} == fitted",
                              description="the operator fits the part the robot holds"),),
    )
