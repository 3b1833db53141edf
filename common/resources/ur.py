"""The UR robot: named poses and a graph of allowed moves between them.

One move ability per target pose P (a template instantiated in a loop):

| predicate | predicate                                                          | control actions | effects        |
|-----------|--------------------------------------------------------------------|-----------------|----------------|
| enabled   | pos_m == ref_pos_c && pos_m in {poses allowed to reach P} && !prot_stop_m | ref_pos_c := P | -        |
| starting  | ref_pos_c == P && pos_m != P && pos_m != unknown (it leaves)       | -               | pos_m := unknown |
| executing | ref_pos_c == P && pos_m == unknown (it is on the way)              | -               | pos_m := P     |
| finished  | ref_pos_c == P && pos_m == P                                       | -               | -              |

`unknown` is the measured pose between named poses. A robot in protective stop
neither accepts a move nor moves.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from common.model import Ability, Domain, Duration, Phase, Resource, Variable, ability, any_of, command, measured

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# A move's half: leaving a pose, or arriving at the next one.
DURATION = Duration.fixed(0.15)

UNKNOWN = "unknown"
DEFAULT_POSES = ("home", "ready")
DEFAULT_MOVES = (("home", "ready"),)

Move = tuple[str, str]


def neighbours(poses: Sequence[str], allowed_moves: Iterable[Move]) -> dict[str, tuple[str, ...]]:
    """The poses the robot may move to from each pose; a move is allowed both ways."""
    adjacent: dict[str, list[str]] = {p: [] for p in poses}
    for a, b in allowed_moves:
        for source, target in ((a, b), (b, a)):
            if source not in adjacent:
                raise ValueError(f"allowed move {a} <-> {b} names {source!r}, which is not a pose")
            if source != target and target not in adjacent[source]:
                adjacent[source].append(target)
    return {p: tuple(ns) for p, ns in adjacent.items()}


def ur(name: str = "ur", poses: Sequence[str] = DEFAULT_POSES, allowed_moves: Iterable[Move] = DEFAULT_MOVES,
       home: str = "home") -> Resource:
    """A UR robot; `allowed_moves` lists pairs of poses it may move between (both ways)."""
    poses = tuple(poses)
    moves = tuple((a, b) for a, b in allowed_moves)
    if UNKNOWN in poses:
        raise ValueError(f"{UNKNOWN!r} is the measured value between poses and cannot be a pose name")
    if home not in poses:
        raise ValueError(f"home pose {home!r} is not one of the poses {poses}")
    graph = neighbours(poses, moves)
    ref_pos_c = command(f"{name}.ref_pos_c", Domain.enum(*poses), home, "the pose the robot is sent to")
    pos_m = measured(f"{name}.pos_m", Domain.enum(*poses, UNKNOWN), home, "the named pose it is at, or unknown")
    prot_stop_m = measured(f"{name}.prot_stop_m", description="protective stop")
    sources = {target: tuple(s for s in poses if target in graph[s]) for target in poses}
    abilities = tuple(_move_to(name, target, sources[target], ref_pos_c, pos_m, prot_stop_m)
                      for target in poses if sources[target])
    return Resource(name, (ref_pos_c, pos_m, prot_stop_m), abilities, device_type="ur",
                    unsafe_for_random_commands=True,
                    parameters={"poses": poses, "allowed_moves": moves, "home": home})


def _move_to(name: str, target: str, sources: tuple[str, ...], ref_pos_c: Variable, pos_m: Variable,
             prot_stop_m: Variable) -> Ability:
    # `pos_m == ref_pos_c` is spelled out per source pose: the two domains differ by
    # `unknown`, and the model refuses comparing variables of different domains.
    at_rest_at_a_source = any_of(*((pos_m == s) & (ref_pos_c == s) for s in sources))
    sent = ref_pos_c == target
    return ability(
        f"{name}.move_to_{target}",
        enabled=Phase(at_rest_at_a_source & ~prot_stop_m, deliberate=f"{ref_pos_c.path} := {target}"),
        starting=Phase(sent & (pos_m != target) & (pos_m != UNKNOWN), effects=[f"{pos_m.path} := {UNKNOWN}"],
                       guard=~prot_stop_m),
        executing=Phase(sent & (pos_m == UNKNOWN), effects=[f"{pos_m.path} := {target}"], guard=~prot_stop_m),
        finished=sent & (pos_m == target),
    )
