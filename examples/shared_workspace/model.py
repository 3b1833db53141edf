"""A cell where two robots share a workspace: a fixture both reach, which at most one may occupy at a time.

* Robot A (`ur_a`, a vacuum gripper `vac_a`) picks brackets from its tray and sets each on
  the product in the fixture, at the bracket's position; at the end it lifts the finished
  product out of the fixture onto its outfeed.
* Robot B (`ur_b`, a nutrunner `nr_b`) fastens each bracket at its screw position in the
  fixture, and between times tightens the bolts of a sub-assembly on its own bench.
* The fixture (`fixture`) clamps the product while brackets are set and fastened.

The fixture poses of both robots form the *shared zone*: a specification keeps the two
robots from being in it at once, so the planner interleaves them (A sets bracket 2
while B tightens a bench bolt, then B fastens bracket 2 while A fetches bracket 3).
Each robot reaches the fixture only through its gate pose (`gate`), and a move to the
gate counts as in the zone, since between poses only the target is known.

Operations (`OPERATION_ORDER`): `ClampProduct`; per bracket k, `PlaceBracket<k>` then
`FastenBracket<k>`; per bench bolt j, `TightenBench<j>`; then `UnclampProduct`,
`UnloadProduct`, `HomeA`, `HomeB`.

Device types the standard templates lack are defined here with the same modelling API
(`ability`/`Phase`) as common/resources: `vacuum_gripper` and `fixture`. They run in
`emulate` mode from this model alone (examples/shared_workspace/hubs.toml).

Global estimated state lives under `cell.`: `cell.bracket<k>_e`, `cell.bench<j>_e` and
`cell.product_e`, recorded by tracking abilities from what the sensors show.
"""

from __future__ import annotations

from collections.abc import Mapping
from itertools import pairwise

from common.model import (
    Ability,
    Domain,
    Model,
    Operation,
    Phase,
    Predicate,
    Resource,
    Specification,
    ability,
    all_of,
    any_of,
    command,
    estimated,
    forbid,
    measured,
    operation,
    tracking,
)
from common.resources import nutrunner, ur

# --- the device types of this cell ------------------------------------------------------


def vacuum_gripper(name: str, robot: str, picks: Mapping[str, object]) -> Resource:
    """A suction cup on `robot`; `picks[pose]` says when a part lies there to be picked.

    | ability | predicate          | control actions        | effects                               |
    |---------|--------------------|------------------------|---------------------------------------|
    | suck    | !on_c              | on_c := T (deliberate) | held_m := T where a part is (it seals) |
    |         | on_c && held_m     | -                      | -                                     |
    | release | on_c && held_m     | on_c := F (deliberate) | -                                     |
    |         | !on_c && held_m    | -                      | held_m := F (the part drops off)      |

    The controller switches the vacuum on only where it picks a part: on anywhere else
    it would suck at nothing and wait there, which no plan may count on.
    """
    on_c = command(f"{name}.on_c", initial=False, description="switch the vacuum on")
    held_m = measured(f"{name}.held_m", description="the vacuum holds (the pressure switch)")
    at_a_part = any_of(*(all_of(f"{robot}.pos_m == {pose}", ready) for pose, ready in picks.items()))
    suck = ability(
        f"{name}.suck",
        enabled=Phase(~on_c & ~held_m, deliberate=f"{on_c.path} := true", guard=at_a_part),
        executing=Phase(on_c & ~held_m, effects=[f"{held_m.path} := true"], guard=at_a_part),
        finished=on_c & held_m,
    )
    release = ability(
        f"{name}.release",
        enabled=Phase(on_c & held_m, deliberate=f"{on_c.path} := false"),
        starting=Phase(~on_c & held_m, effects=[f"{held_m.path} := false"]),
        finished=~on_c & ~held_m,
    )
    # Losing the command must not drop the part: the vacuum stays as it is.
    return Resource(name, (on_c, held_m), (suck, release), device_type="vacuum_gripper",
                    parameters={"robot": robot, "picks": dict(picks), "emulated_delay": 0.15, "safe_state": {}})


def fixture(name: str) -> Resource:
    """The product fixture: pneumatic clamps, commanded and measured (a clamp sensor)."""
    clamp_c = command(f"{name}.clamp_c", initial=False, description="close the clamps")
    clamped_m = measured(f"{name}.clamped_m", description="the clamps are closed")
    clamp = ability(
        f"{name}.clamp",
        enabled=Phase(~clamp_c & ~clamped_m, deliberate=f"{clamp_c.path} := true"),
        executing=Phase(clamp_c & ~clamped_m, effects=[f"{clamped_m.path} := true"]),
        finished=clamp_c & clamped_m,
    )
    unclamp = ability(
        f"{name}.unclamp",
        enabled=Phase(clamp_c & clamped_m, deliberate=f"{clamp_c.path} := false"),
        executing=Phase(~clamp_c & clamped_m, effects=[f"{clamped_m.path} := false"]),
        finished=~clamp_c & ~clamped_m,
    )
    # A fixture that lost its commands keeps its clamps as they are: never let go of the product.
    return Resource(name, (clamp_c, clamped_m), (clamp, unclamp), device_type="fixture",
                    parameters={"emulated_delay": 0.25, "safe_state": {}})


# --- the cell --------------------------------------------------------------------------
BRACKET_COUNT = 4
BENCH_COUNT = 4
BRACKETS = tuple(range(1, BRACKET_COUNT + 1))
BENCH_BOLTS = tuple(range(1, BENCH_COUNT + 1))
BRACKET_STATES = Domain.enum("in_tray", "held", "placed", "fastened")
BENCH_STATES = Domain.enum("placed", "tightened")
PRODUCT_STATES = Domain.enum("in_fixture", "held", "out")
PRODUCT = "cell.product_e"

HOME, GATE = "home", "gate"
# Robot A: its tray and outfeed (its own), the bracket positions and the product in the fixture (shared).
TRAY_POSES = tuple(f"tray{k}" for k in BRACKETS)
PLACE_POSES = tuple(f"place{k}" for k in BRACKETS)
LIFT_POSE = "lift_product"
OUT_POSE = "outfeed"
POSES_A = (HOME, *TRAY_POSES, OUT_POSE, GATE, *PLACE_POSES, LIFT_POSE)
SHARED_A = (*PLACE_POSES, LIFT_POSE)
MOVES_A = (
    *((HOME, p) for p in TRAY_POSES),
    (HOME, OUT_POSE), (HOME, GATE),
    *((GATE, p) for p in SHARED_A),
    *pairwise(PLACE_POSES),
)
# Robot B: its bench (its own; the bolts form a ring with home), the screw positions in the fixture (shared).
BENCH_POSES = tuple(f"bench{j}" for j in BENCH_BOLTS)
SCREW_POSES = tuple(f"screw{k}" for k in BRACKETS)
POSES_B = (HOME, *BENCH_POSES, GATE, *SCREW_POSES)
SHARED_B = SCREW_POSES
MOVES_B = (
    (HOME, BENCH_POSES[0]), *pairwise(BENCH_POSES), (BENCH_POSES[-1], HOME),
    (HOME, GATE),
    *((GATE, p) for p in SCREW_POSES),
    *pairwise(SCREW_POSES),
)

OPERATION_ORDER = (
    "ClampProduct",
    *(name for k in BRACKETS for name in (f"PlaceBracket{k}", f"FastenBracket{k}")),
    *(f"TightenBench{j}" for j in BENCH_BOLTS),
    "UnclampProduct", "UnloadProduct", "HomeA", "HomeB",
)


def bracket(k: int) -> str:
    return f"cell.bracket{k}_e"


def bench(j: int) -> str:
    return f"cell.bench{j}_e"


def build_model() -> Model:
    picks = {TRAY_POSES[k - 1]: f"{bracket(k)} == in_tray" for k in BRACKETS}
    picks[LIFT_POSE] = f"{PRODUCT} == in_fixture"
    resources = (
        ur("ur_a", POSES_A, MOVES_A, HOME),
        vacuum_gripper("vac_a", "ur_a", picks),
        ur("ur_b", POSES_B, MOVES_B, HOME),
        nutrunner("nr_b"),
        fixture("fixture"),
    )
    variables = (
        *(estimated(bracket(k), BRACKET_STATES, "in_tray", f"bracket {k}") for k in BRACKETS),
        *(estimated(bench(j), BENCH_STATES, "placed", f"bench bolt {j}") for j in BENCH_BOLTS),
        estimated(PRODUCT, PRODUCT_STATES, "in_fixture", "the product"),
    )
    return Model("shared_workspace", resources, variables, _tracking(), _operations(), _specifications())


def _tracking() -> tuple[Ability, ...]:
    abilities: list[Ability] = []
    for k, tray, place, screw in zip(BRACKETS, TRAY_POSES, PLACE_POSES, SCREW_POSES, strict=True):
        abilities += [
            tracking(f"cell.bracket{k}_picked", all_of(f"{bracket(k)} == in_tray", "vac_a.held_m",
                                                       f"ur_a.pos_m == {tray}"), f"{bracket(k)} := held"),
            tracking(f"cell.bracket{k}_placed", all_of(f"{bracket(k)} == held", "!vac_a.held_m",
                                                       f"ur_a.pos_m == {place}"), f"{bracket(k)} := placed"),
            tracking(f"cell.bracket{k}_fastened", all_of(f"{bracket(k)} == placed", "nr_b.tqr_m", "fixture.clamped_m",
                                                         f"ur_b.pos_m == {screw}"), f"{bracket(k)} := fastened"),
        ]
    abilities += [tracking(f"cell.bench{j}_tightened", all_of(f"{bench(j)} == placed", "nr_b.tqr_m",
                                                              f"ur_b.pos_m == {pose}"), f"{bench(j)} := tightened")
                  for j, pose in zip(BENCH_BOLTS, BENCH_POSES, strict=True)]
    abilities += [
        tracking("cell.product_lifted",
                 all_of(f"{PRODUCT} == in_fixture", "vac_a.held_m", f"ur_a.pos_m == {LIFT_POSE}"),
                 f"{PRODUCT} := held"),
        tracking("cell.product_out", all_of(f"{PRODUCT} == held", "!vac_a.held_m", f"ur_a.pos_m == {OUT_POSE}"),
                 f"{PRODUCT} := out"),
    ]
    return tuple(abilities)


def _operations() -> tuple[Operation, ...]:
    all_fastened = all_of(*(f"{bracket(k)} == fastened" for k in BRACKETS))
    all_benched = all_of(*(f"{bench(j)} == tightened" for j in BENCH_BOLTS))
    operations = [
        operation("ClampProduct", f"{PRODUCT} == in_fixture && !fixture.clamp_c", "fixture.clamped_m",
                  description="the fixture clamps the product"),
        *(operation(f"PlaceBracket{k}", f"{bracket(k)} == in_tray", f"{bracket(k)} == placed",
                    description=f"robot A sets bracket {k} on the product") for k in BRACKETS),
        *(operation(f"FastenBracket{k}", f"{bracket(k)} == placed", f"{bracket(k)} == fastened",
                    description=f"robot B fastens bracket {k}") for k in BRACKETS),
        *(operation(f"TightenBench{j}", f"{bench(j)} == placed", f"{bench(j)} == tightened",
                    description=f"robot B tightens bolt {j} on its bench") for j in BENCH_BOLTS),
        operation("UnclampProduct", all_fastened, "!fixture.clamped_m", description="the fixture lets go"),
        operation("UnloadProduct", all_fastened, f"{PRODUCT} == out",
                  description="robot A lifts the product onto its outfeed"),
        operation("HomeA", f"{PRODUCT} == out", f"ur_a.pos_m == {HOME} && !vac_a.on_c",
                  description="robot A goes home"),
        operation("HomeB", all_of(all_fastened, all_benched), f"ur_b.pos_m == {HOME}",
                  description="robot B goes home"),
    ]
    by_name = {op.name: op for op in operations}
    return tuple(by_name[name] for name in OPERATION_ORDER)


def _in_zone(robot: str, shared: tuple[str, ...]) -> Predicate:
    """The robot at a shared pose, sent to one, or on its way to its gate (from a shared pose or not)."""
    return any_of(*(f"{robot}.pos_m == {p}" for p in shared), *(f"{robot}.ref_pos_c == {p}" for p in shared),
                  all_of(f"{robot}.ref_pos_c == {GATE}", f"{robot}.pos_m == unknown"))


def _specifications() -> tuple[Specification, ...]:
    lets_go = all_of("!vac_a.on_c", "vac_a.held_m")
    where_it_belongs = any_of(
        *(all_of(f"{bracket(k)} == held", f"ur_a.pos_m == {place}") for k, place in zip(BRACKETS, PLACE_POSES,
                                                                                       strict=True)),
        all_of(f"{PRODUCT} == held", f"ur_a.pos_m == {OUT_POSE}"),
    )
    on_the_product = any_of(*(f"ur_a.pos_m == {p}" for p in PLACE_POSES))
    at_a_screw = any_of(*(f"ur_b.pos_m == {p}" for p in SCREW_POSES))
    return (
        forbid("both_robots_in_shared_zone", _in_zone("ur_a", SHARED_A) & _in_zone("ur_b", SHARED_B),
               "at most one robot is in the shared zone around the fixture"),
        forbid("part_dropped", lets_go & ~where_it_belongs,
               "robot A lets go of a bracket only at its place, and of the product only on the outfeed"),
        forbid("bracket_set_on_loose_product", lets_go & on_the_product & all_of("!fixture.clamped_m"),
               "brackets are set only on the clamped product"),
        forbid("fastening_loose_product", all_of("nr_b.run_m", "!fixture.clamped_m") & at_a_screw,
               "robot B fastens only on the clamped product"),
        forbid("product_lifted_while_clamped",
               all_of("vac_a.held_m", f"ur_a.pos_m == {LIFT_POSE}", "fixture.clamp_c"),
               "robot A lifts the product only once the fixture lets go"),
        forbid("robot_moves_while_its_nutrunner_runs", "nr_b.run_m && ur_b.pos_m == unknown",
               "robot B stands still while its nutrunner runs"),
    )
