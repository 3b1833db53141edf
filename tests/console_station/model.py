"""A small station for the console tests: an operator places two bolts, the robot's nutrunner tightens them.

The fault station's robot and nutrunner (tests/fault_station/model.py) plus the
operator, so that every console action has something to act on: `PlaceBolts` waits for
the operator's confirmation (the console's `confirm`), `TightenBolt<i>` for the robot.
Plans take milliseconds; the whole run takes a few seconds.
"""

from __future__ import annotations

from common.model import Domain, Model, all_of, estimated, forbid, operation, tracking
from common.resources import nutrunner, operator, ur

BOLTS = (1, 2)
BOLT_STATES = Domain.enum("absent", "placed", "tightened")
POSES = ("home", *(f"at_bolt{i}" for i in BOLTS))
MOVES = (("home", "at_bolt1"), ("home", "at_bolt2"), ("at_bolt1", "at_bolt2"))


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def build_model() -> Model:
    human = operator("human", ("place_bolts",), on_confirm={"place_bolts": [f"{bolt(i)} := placed" for i in BOLTS]})
    return Model(
        "console_station",
        (ur("ur", POSES, MOVES, "home"), nutrunner("nr"), human),
        estimated=tuple(estimated(bolt(i), BOLT_STATES, "absent", f"bolt {i}") for i in BOLTS),
        tracking=tuple(tracking(f"engine.bolt{i}_tightened",
                                f"{bolt(i)} == placed && nr.tqr_m && ur.pos_m == at_bolt{i}",
                                f"{bolt(i)} := tightened") for i in BOLTS),
        operations=(
            operation("PlaceBolts", all_of(*(f"{bolt(i)} == absent" for i in BOLTS)),
                      all_of(*(f"{bolt(i)} == placed" for i in BOLTS)), description="the operator places the bolts"),
            *(operation(f"TightenBolt{i}", f"{bolt(i)} == placed", f"{bolt(i)} == tightened",
                        description=f"the robot tightens bolt {i}") for i in BOLTS),
        ),
        specifications=(
            forbid("robot_moves_while_the_nutrunner_runs", "nr.run_m && ur.pos_m == unknown",
                   "the robot stands still while the nutrunner it holds is running"),
        ),
    )
