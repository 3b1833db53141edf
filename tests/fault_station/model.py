"""A small station that plans in milliseconds, for the fault tests and the benchmarks.

A UR-like robot with a home pose and one pose per bolt (`home` is next to every bolt,
and the bolts form a chain), the nutrunner it holds, and 4 bolts: global estimated
variables `engine.bolt<i>_e` (placed -> tightened) set by tracking abilities when the
nutrunner reports torque while the robot is at the bolt, as in the reference station.
One planning operation per bolt, `TightenBolt<i>`, whose goal is the bolt tightened.

One specification, as in the reference station: the robot stands still while the
nutrunner runs (so a tightening always happens at one pose).

`bolt_station` builds it for any number of bolts; the test line's station (tests/line_station/model.py)
is the same station with two bolts that are the product's variables.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise

from common.model import Domain, Model, estimated, forbid, operation, tracking
from common.resources import nutrunner, ur

BOLTS = (1, 2, 3, 4)
BOLT_STATES = Domain.enum("placed", "tightened")
HOME = "home"


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def bolt_pose(i: int) -> str:
    return f"at_bolt{i}"


BOLT_POSES = {i: bolt_pose(i) for i in BOLTS}


def bolt_station(name: str, bolts: Sequence[int], *, product: Sequence[str] = ()) -> Model:
    """The robot, its nutrunner and `bolts` (numbered in chain order); `product`: the product's variables."""
    poses = {i: bolt_pose(i) for i in bolts}
    moves = (*((HOME, pose) for pose in poses.values()),
             *((poses[a], poses[b]) for a, b in pairwise(bolts)))
    return Model(
        name,
        (ur("ur", (HOME, *poses.values()), moves, HOME), nutrunner("nr")),
        estimated=tuple(estimated(bolt(i), BOLT_STATES, "placed", f"bolt {i}") for i in bolts),
        tracking=tuple(
            tracking(f"engine.bolt{i}_tightened",
                     f"{bolt(i)} == placed && nr.tqr_m && ur.pos_m == {poses[i]}",
                     f"{bolt(i)} := tightened")
            for i in bolts
        ),
        operations=tuple(operation(f"TightenBolt{i}", f"{bolt(i)} == placed", f"{bolt(i)} == tightened",
                                   description=f"the robot tightens bolt {i}")
                         for i in bolts),
        specifications=(
            forbid("robot_moves_while_the_nutrunner_runs", "nr.run_m && ur.pos_m == unknown",
                   "the robot stands still while the nutrunner it holds is running"),
        ),
        product=tuple(product),
    )


def build_model() -> Model:
    return bolt_station("fault_station", BOLTS)
