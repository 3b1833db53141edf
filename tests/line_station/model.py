"""A small station of the test line: the fault station's robot and nutrunner, two bolts, and the bolts
as the product's variables, so that each order starts from placed bolts and archives them tightened."""

from __future__ import annotations

from common.model import Domain, Model, estimated, forbid, operation, tracking
from common.resources import nutrunner, ur

BOLTS = (1, 2)
BOLT_STATES = Domain.enum("placed", "tightened")
HOME = "home"
BOLT_POSES = {i: f"at_bolt{i}" for i in BOLTS}
POSES = (HOME, *BOLT_POSES.values())
MOVES = (*((HOME, p) for p in BOLT_POSES.values()), (BOLT_POSES[1], BOLT_POSES[2]))


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def build_model() -> Model:
    return Model(
        "line_station",
        (ur("ur", POSES, MOVES, HOME), nutrunner("nr")),
        estimated=tuple(estimated(bolt(i), BOLT_STATES, "placed", f"bolt {i}") for i in BOLTS),
        tracking=tuple(
            tracking(f"engine.bolt{i}_tightened",
                     f"{bolt(i)} == placed && nr.tqr_m && ur.pos_m == {BOLT_POSES[i]}",
                     f"{bolt(i)} := tightened")
            for i in BOLTS
        ),
        operations=tuple(operation(f"TightenBolt{i}", f"{bolt(i)} == placed", f"{bolt(i)} == tightened",
                                   description=f"the robot tightens bolt {i}")
                         for i in BOLTS),
        specifications=(
            forbid("robot_moves_while_the_nutrunner_runs", "nr.run_m && ur.pos_m == unknown",
                   "the robot stands still while the nutrunner it holds is running"),
        ),
        product=("engine.*",),
    )
