"""The synthetic N-bolt station for the planner benchmark.

A robot on a ring of `poses` poses (`p0` .. `p<poses-1>`, each adjacent to its two ring
neighbours, `p0` home) holding the nutrunner, and N bolts: bolt i (1..N) sits at pose
`p<i % poses>`. One tracking ability and one operation (`TightenBolt<i>`) per bolt, as
in the reference station but without tool changes or an operator, so that plan length
grows with N alone.
"""

from __future__ import annotations

from common.model import Domain, Model, estimated, operation, tracking
from common.resources import nutrunner, ur

BOLT_STATES = Domain.enum("placed", "tightened")


def pose(index: int) -> str:
    return f"p{index}"


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def build_model(bolts: int, poses: int = 10) -> Model:
    if bolts < 0:
        raise ValueError(f"bolts must be 0 or more, got {bolts}")
    if poses < 1:
        raise ValueError(f"poses must be 1 or more, got {poses}")
    ring = tuple(pose(k) for k in range(poses))
    moves = tuple((ring[k], ring[(k + 1) % poses]) for k in range(poses) if poses > 1)
    numbers = range(1, bolts + 1)
    robot = ur("ur", ring, moves, home=ring[0])
    return Model(
        f"synthetic_{bolts}_bolts_{poses}_poses",
        (robot, nutrunner("nr")),
        estimated=tuple(estimated(bolt(i), BOLT_STATES, "placed", f"bolt {i}") for i in numbers),
        tracking=tuple(
            tracking(f"engine.bolt{i}_tightened",
                     f"{bolt(i)} == placed && nr.tqr_m && ur.pos_m == {pose(i % poses)}",
                     f"{bolt(i)} := tightened")
            for i in numbers
        ),
        operations=tuple(operation(f"TightenBolt{i}", f"{bolt(i)} == placed", f"{bolt(i)} == tightened")
                         for i in numbers),
    )
