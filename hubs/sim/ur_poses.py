"""Joint targets for a station's named robot poses, for the fake UR controller in sim mode.

A station model names its robot poses (`ur.ref_pos_c`'s domain) and the moves allowed
between them, but not where they are: on the real cell they are taught. In sim mode
every pose gets a joint target, generated deterministically from its name (the same
name always gets the same target, whatever else the station has), so that a run can
be repeated and a pose table can be printed and compared.

The fake moves in joint space along a straight line, and the driver reads `pos_m` as
the pose whose every joint is within `joint_tolerance` (0.01 rad) of the robot's, else
`unknown`. So the table must keep every pose apart from every other one and from every
allowed move between two others: a move from A to B must read A, unknown, B, never a
third pose on the way (the model's `move_to` ability has no such step).
`check_pose_table` verifies exactly that, with a margin; `pose_table` draws targets
again (with a salt) until it holds.

The home pose is the fake's start position (`hubs.sim.ur_robot.HOME_Q`): the model
starts with the robot at home.
"""

from __future__ import annotations

import random
import zlib
from collections.abc import Iterable, Mapping, Sequence

from hubs.sim.ur_robot import HOME_Q

Joints = tuple[float, ...]
SPREAD = 0.5  # rad around home, per joint: a move takes well under a second at 1.05 rad/s
MARGIN = 0.05  # rad: five times the driver's default joint tolerance
MAX_SALT = 1000


def _draw(name: str, salt: int) -> Joints:
    rng = random.Random(zlib.crc32(f"{name}#{salt}".encode()))
    return tuple(round(h + rng.uniform(-SPREAD, SPREAD), 4) for h in HOME_Q)


def distance(a: Sequence[float], b: Sequence[float]) -> float:
    """Chebyshev distance: how far the worst joint is off (the driver's pose test)."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def segment_distance(point: Sequence[float], a: Sequence[float], b: Sequence[float]) -> float:
    """Smallest Chebyshev distance from `point` to the straight joint-space move a → b.
    The distance along the move is convex, so a ternary search finds its minimum."""
    def at(t: float) -> float:
        return distance(point, [x + t * (y - x) for x, y in zip(a, b, strict=True)])

    lo, hi = 0.0, 1.0
    for _ in range(40):
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        if at(m1) <= at(m2):
            hi = m2
        else:
            lo = m1
    return min(at(lo), at(0.0), at(1.0))


def check_pose_table(table: Mapping[str, Sequence[float]], moves: Iterable[tuple[str, str]],
                     margin: float = MARGIN) -> list[str]:
    """The problems of a pose table: poses closer than `margin` to each other, or to a move between two others."""
    problems = []
    names = list(table)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if distance(table[a], table[b]) < margin:
                problems.append(f"poses {a} and {b} are {distance(table[a], table[b]):.3f} rad apart")
    for a, b in moves:
        for p in names:
            if p in (a, b):
                continue
            gap = segment_distance(table[p], table[a], table[b])
            if gap < margin:
                problems.append(f"the move {a} <-> {b} passes {gap:.3f} rad from pose {p}")
    return problems


def _fits(name: str, q: Joints, table: Mapping[str, Joints], moves: Sequence[tuple[str, str]]) -> bool:
    """`q` for `name` keeps `MARGIN` from the placed poses, from their moves, and its own moves from them."""
    if any(distance(q, other) < MARGIN for other in table.values()):
        return False
    if any(segment_distance(q, table[a], table[b]) < MARGIN for a, b in moves if a in table and b in table):
        return False
    mine = [b if a == name else a for a, b in moves if name in (a, b)]
    return not any(segment_distance(table[p], q, table[n]) < MARGIN
                   for n in mine if n in table for p in table if p != n)


def pose_table(poses: Sequence[str], moves: Iterable[tuple[str, str]], home: str) -> dict[str, Joints]:
    """A joint target per pose (home = the fake's start), every pose and move apart by `MARGIN`."""
    moves = [(a, b) for a, b in moves]
    table: dict[str, Joints] = {home: tuple(HOME_Q)}
    for name in poses:
        if name == home:
            continue
        for salt in range(MAX_SALT):
            q = _draw(name, salt)
            if _fits(name, q, table, moves):
                table[name] = q
                break
        else:
            raise ValueError(f"no joint target for pose {name!r} keeps {MARGIN} rad from the others")
    return {name: table[name] for name in poses}


def driver_poses(table: Mapping[str, Sequence[float]]) -> dict[str, dict[str, list[float]]]:
    """The table as the UR driver's `poses` parameter: `{name: {"q": [6 joint angles]}}`."""
    return {name: {"q": list(q)} for name, q in table.items()}
