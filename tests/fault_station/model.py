"""A small station that plans in milliseconds, for the fault tests and the benchmarks.

A UR-like robot with a home pose and one pose per bolt (`home` is next to every bolt,
and the bolts form a chain), the nutrunner it holds, and 4 bolts: global estimated
variables `engine.bolt<i>_e` (placed -> tightened) set by tracking abilities when the
nutrunner reports torque while the robot is at the bolt, as in the reference station.
One planning operation per bolt, `TightenBolt<i>`, whose goal is the bolt tightened.

One specification, as in the reference station: the robot stands still while the
nutrunner runs (so a tightening always happens at one pose).
"""

from __future__ import annotations

from common.model import Domain, Model, estimated, forbid, operation, tracking
from common.resources import nutrunner, ur

BOLTS = (1, 2, 3, 4)
BOLT_STATES = Domain.enum("placed", "tightened")
HOME = "home"
BOLT_POSES = {i: f"at_bolt{i}" for i in BOLTS}
POSES = (HOME, *BOLT_POSES.values())
MOVES = (*((HOME, p) for p in BOLT_POSES.values()),
         *((BOLT_POSES[i], BOLT_POSES[i + 1]) for i in BOLTS[:-1]))


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def build_model() -> Model:
    return Model(
        "fault_station",
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
    )
