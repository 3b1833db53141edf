"""Random small stations with timing (issue 21, item 6): robots taking boxes from feeders whose sensors race them.

`build_random_timed_station(seed, *, followable=True)` draws, from one `random.Random(seed)`:

* 1..3 UR robots (`r<j>`), each with a vacuum gripper (`g<j>`) and a drop pose: its own (`drop<j>`)
  or one pallet all robots share (`pallet`, a zone no two robots may be in or sent to at once);
* 1..2 box feeders (`f<k>`, pose `at_f<k>`), each served by one or more robots: a feeder served by
  several is a shared zone, with the same rule. A feeder's "box taken" sensor is a transient sensor:
  an effect of the feeder whose guard reads other devices' measured values (a robot it serves stands
  at it with its vacuum on), as the feeder of tests/timing_stations/feeder.py;
* 1..4 boxes, each on one feeder, fed in order and handed over robot -> gripper -> feeder's sensor
  -> the robot's drop (`cell.box<i>_e`: waiting -> on_feeder -> held_by_r<j> -> placed), one `Place<i>` each;
* a duration interval per resource, drawn so that each feeder's sensor races its robots in one of the
  ways of `SensorTiming`.

With `followable=True` every feeder's timing leaves a plan the devices can follow: its sensor registers
before any of its robots can leave (`FASTER`), a specification keeps a robot at the feeder while the
sensor's effect is due (`GUARDED`), or the sensor is slower and the controller must keep the robot there
(`WAITED_FOR`, issue 21's race: the plan that waits exists, the shortest one may not). With
`followable=False` every robot's own program leaves a feeder as soon as its vacuum holds there, before
any sensor can register (`UNAVOIDABLE`, as `build_model(unavoidable=True)` of the feeder station): no
plan places a box, and the controller must say so rather than go round in circles.
"""

from __future__ import annotations

import dataclasses
import random
from dataclasses import dataclass
from enum import Enum

from common.model import (
    Ability,
    Domain,
    Duration,
    Model,
    Operation,
    Phase,
    Predicate,
    Resource,
    Specification,
    ability,
    all_of,
    any_of,
    automatic,
    command,
    estimated,
    forbid,
    measured,
    operation,
    tracking,
)
from common.resources import ur

HOME = "home"
SHARED_PALLET = "pallet"
# Between two drawn intervals that must not overlap: what separates "before" from "after" safely.
MARGIN_S = 0.02


class SensorTiming(Enum):
    """How a feeder's "box taken" sensor races the robots it serves."""

    FASTER = "faster"  # its slowest registration comes before any robot's quickest leaving
    GUARDED = "guarded"  # slower, but a specification forbids sending a robot away while it is due
    WAITED_FOR = "waited_for"  # slower: only the controller's waiting keeps the robot there
    UNAVOIDABLE = "unavoidable"  # slower, and the robot's own program leaves as soon as its vacuum holds

    @property
    def followable(self) -> bool:
        return self is not SensorTiming.UNAVOIDABLE


# The timings drawn for a followable station. GUARDED is followable too, but with two or more boxes the controller
# does not follow it yet (seeds 25, 30, 60, 68, 157, 158, 167, 336 with `timings=WITH_GUARDED`): its
# plans toggle the vacuum around the specification's guard, and the gripper's drawn durations make the state
# leave them at the same two places until the goals are given up. Plans are not yet checked against every
# timing of their effects (issue 21, item 2): until they are, GUARDED is drawn only when asked for.
FOLLOWABLE_TIMINGS = (SensorTiming.FASTER, SensorTiming.WAITED_FOR)
WITH_GUARDED = tuple(t for t in SensorTiming if t.followable)


@dataclass(frozen=True)
class Feeder:
    name: str
    robots: tuple[str, ...]  # the robots it serves
    timing: SensorTiming

    @property
    def pose(self) -> str:
        return f"at_{self.name}"


@dataclass(frozen=True)
class Shape:
    """What was drawn, for a failure message to say what station a seed builds."""

    robots: tuple[str, ...]
    feeders: tuple[Feeder, ...]
    boxes: tuple[str, ...]  # box i's feeder, in order
    shared_pallet: bool
    durations: dict[str, Duration]

    def describe(self) -> str:
        feeders = "; ".join(f"{f.name} ({f.timing.value}, {self.durations[f.name]}) for {', '.join(f.robots)}"
                            for f in self.feeders)
        robots = ", ".join(f"{r} ({self.durations[r]})" for r in self.robots)
        pallet = "a shared pallet" if self.shared_pallet else "a drop pose each"
        return f"robots {robots} with {pallet}; feeders {feeders}; boxes on {', '.join(self.boxes)}"


def box(i: int) -> str:
    return f"cell.box{i}_e"


def gripper_of(robot: str) -> str:
    return f"g{robot.removeprefix('r')}"


def build_random_timed_station(seed: int, *, followable: bool = True,
                               timings: tuple[SensorTiming, ...] = FOLLOWABLE_TIMINGS) -> Model:
    return build_random_timed_station_with_shape(seed, followable=followable, timings=timings)[0]


def build_random_timed_station_with_shape(seed: int, *, followable: bool = True,
                                          timings: tuple[SensorTiming, ...] = FOLLOWABLE_TIMINGS
                                          ) -> tuple[Model, Shape]:
    rng = random.Random(seed)
    robots = tuple(f"r{j}" for j in range(1, rng.choices((1, 2, 3), weights=(4, 5, 1))[0] + 1))
    feeder_names = tuple(f"f{k}" for k in range(1, rng.randint(1, 2) + 1))
    served = _serving(rng, robots, feeder_names)
    feeders = tuple(Feeder(name, served[name], rng.choice(timings) if followable
                           else SensorTiming.UNAVOIDABLE)
                    for name in feeder_names)
    boxes = tuple(rng.choice(feeder_names) for _ in range(rng.randint(1, 4 if len(robots) > 1 else 3)))
    shared_pallet = len(robots) > 1 and rng.random() < 0.5
    durations = _durations(rng, robots, feeders)
    shape = Shape(robots, feeders, boxes, shared_pallet, durations)
    return _model(seed, shape, followable), shape


def _serving(rng: random.Random, robots: tuple[str, ...], feeders: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """Each feeder served by at least one robot, each robot serving at least one feeder; some feeders shared."""
    served: dict[str, set[str]] = {f: set() for f in feeders}
    for j, robot in enumerate(robots):
        served[feeders[j % len(feeders)]].add(robot)
    for f in feeders:
        if not served[f]:
            served[f].add(rng.choice(robots))
        for robot in robots:
            if rng.random() < 0.4:
                served[f].add(robot)
    return {f: tuple(sorted(rs)) for f, rs in served.items()}


def _interval(rng: random.Random, low: float, high: float) -> Duration:
    """A duration within [low, high], an interval as often as not."""
    a, b = sorted((round(rng.uniform(low, high), 3), round(rng.uniform(low, high), 3)))
    return Duration.fixed(a) if rng.random() < 0.3 else Duration(a, b)


def _durations(rng: random.Random, robots: tuple[str, ...], feeders: tuple[Feeder, ...]) -> dict[str, Duration]:
    durations: dict[str, Duration] = {}
    for robot in robots:
        durations[robot] = _interval(rng, 0.1, 0.4)
        durations[gripper_of(robot)] = _interval(rng, 0.05, 0.2)
    for feeder in feeders:
        quickest_leave = min(durations[r].min_s for r in feeder.robots)
        slowest_leave = max(durations[r].max_s for r in feeder.robots)
        if feeder.timing is SensorTiming.FASTER:
            durations[feeder.name] = _interval(rng, 0.01, quickest_leave - MARGIN_S)
        else:  # the sensor's quickest registration comes after every robot can have left
            durations[feeder.name] = _interval(rng, slowest_leave + MARGIN_S, slowest_leave + 0.3)
    return durations


def _model(seed: int, shape: Shape, followable: bool) -> Model:
    feeders_of = {r: tuple(f for f in shape.feeders if r in f.robots) for r in shape.robots}
    drop = {r: SHARED_PALLET if shape.shared_pallet else f"drop{r.removeprefix('r')}" for r in shape.robots}
    resources: list[Resource] = []
    for robot in shape.robots:
        resources.append(_robot(robot, feeders_of[robot], drop[robot], shape.durations[robot],
                                leaves_when_gripped=not followable))
        resources.append(_vacuum_gripper(gripper_of(robot), robot, drop[robot], shape.durations[gripper_of(robot)]))
    for feeder in shape.feeders:
        resources.append(_box_feeder(feeder, shape.durations[feeder.name]))

    box_states = Domain.enum("waiting", "on_feeder", *(f"held_by_{r}" for r in shape.robots), "placed")
    boxes = tuple(range(1, len(shape.boxes) + 1))
    variables = tuple(estimated(box(i), box_states, "waiting", f"box {i}, on feeder {shape.boxes[i - 1]}")
                      for i in boxes)
    tracked: list[Ability] = []
    for i, feeder_name in zip(boxes, shape.boxes, strict=True):
        feeder = next(f for f in shape.feeders if f.name == feeder_name)
        # Boxes on one feeder come in order: the next arrives once the one before has been taken.
        before = [k for k in boxes if k < i and shape.boxes[k - 1] == feeder_name]
        gone = (f"{box(before[-1])} != waiting", f"{box(before[-1])} != on_feeder") if before else ()
        tracked.append(tracking(f"cell.box{i}_arrives", all_of(f"{box(i)} == waiting", f"{feeder.name}.present_m",
                                                                 *gone), f"{box(i)} := on_feeder"))
        for robot in feeder.robots:
            # A gripper holds one box: a robot that comes back with one does not take the next.
            empty = (f"{box(k)} != held_by_{robot}" for k in boxes if k != i)
            tracked.append(tracking(
                f"cell.box{i}_taken_by_{robot}",
                all_of(f"{box(i)} == on_feeder", f"!{feeder.name}.present_m", f"{robot}.pos_m == {feeder.pose}",
                       f"{gripper_of(robot)}.vac_m", *empty),
                f"{box(i)} := held_by_{robot}"))
        for robot in shape.robots:
            tracked.append(tracking(
                f"cell.box{i}_placed_by_{robot}",
                all_of(f"{box(i)} == held_by_{robot}", f"{robot}.pos_m == {drop[robot]}",
                       f"!{gripper_of(robot)}.vac_m"),
                f"{box(i)} := placed"))
    operations: tuple[Operation, ...] = tuple(
        operation(f"Place{i}", f"{box(i)} != placed", f"{box(i)} == placed") for i in boxes)
    return Model(f"random_timed_{seed}", tuple(resources), variables, tuple(tracked), operations,
                 tuple(_specifications(shape)))


def _robot(name: str, feeders: tuple[Feeder, ...], drop: str, duration: Duration, *,
           leaves_when_gripped: bool) -> Resource:
    """A UR robot going home <-> each of its feeders <-> its drop <-> home. `leaves_when_gripped`: its own
    program sends it from a feeder to its drop as soon as the vacuum holds there (no plan can hold it)."""
    poses = (HOME, *(f.pose for f in feeders), drop)
    moves = [(HOME, drop), *((HOME, f.pose) for f in feeders), *((f.pose, drop) for f in feeders)]
    robot = ur(name, poses, moves, HOME)
    abilities = robot.abilities
    if leaves_when_gripped:
        vac_m = f"{gripper_of(name)}.vac_m"
        for f in feeders:
            at_feeder = all_of(f"{name}.pos_m == {f.pose}", f"{name}.ref_pos_c == {f.pose}", vac_m)
            leave = automatic(f"{name}.leave_{f.name}_when_gripped", at_feeder, f"{name}.ref_pos_c := {drop}")
            abilities += (ability(f"{name}.leave_{f.name}_when_gripped", enabled=at_feeder, extra=[leave]),)
    return dataclasses.replace(robot, abilities=abilities, duration=duration)


def _vacuum_gripper(name: str, robot: str, drop: str, duration: Duration) -> Resource:
    """A vacuum gripper on `robot`; the controller lets go only over the drop (elsewhere the box would fall)."""
    vac_c = command(f"{name}.vac_c", initial=False, description="switch the vacuum on")
    vac_m = measured(f"{name}.vac_m", description="the vacuum holds")
    grip = ability(f"{name}.grip",
                   enabled=Phase(~vac_c & ~vac_m, deliberate=f"{vac_c.path} := true"),
                   executing=Phase(vac_c & ~vac_m, effects=[f"{vac_m.path} := true"]),
                   finished=vac_c & vac_m)
    release = ability(f"{name}.release",
                      enabled=Phase(vac_c & vac_m, deliberate=f"{vac_c.path} := false",
                                    guard=f"{robot}.pos_m == {drop}"),
                      executing=Phase(~vac_c & vac_m, effects=[f"{vac_m.path} := false"]),
                      finished=~vac_c & ~vac_m)
    return Resource(name, (vac_c, vac_m), (grip, release), device_type="vacuum_gripper", duration=duration)


def _box_feeder(feeder: Feeder, duration: Duration) -> Resource:
    """`feed` brings the next box; the sensor reports it taken while a robot it serves holds it there."""
    name = feeder.name
    feed_c = command(f"{name}.feed_c", initial=False, description="bring the next box")
    present_m = measured(f"{name}.present_m", initial=True, description="a box stands at the pick position")
    feed = ability(f"{name}.feed",
                   enabled=Phase(~feed_c & ~present_m, deliberate=f"{feed_c.path} := true"),
                   executing=Phase(feed_c & ~present_m, effects=[f"{present_m.path} := true"]),
                   finished=Phase(feed_c & present_m, automatic=f"{feed_c.path} := false"))
    held_here = any_of(*(all_of(f"{r}.pos_m == {feeder.pose}", f"{gripper_of(r)}.vac_m") for r in feeder.robots))
    taken = ability(f"{name}.taken",
                    executing=Phase(all_of(present_m, ~feed_c, held_here), effects=[f"{present_m.path} := false"]))
    return Resource(name, (feed_c, present_m), (feed, taken), device_type="box_feeder", duration=duration)


def _specifications(shape: Shape) -> list[Specification]:
    specifications: list[Specification] = []
    zones = [(f.pose, f.robots) for f in shape.feeders if len(f.robots) > 1]
    if shape.shared_pallet:
        zones.append((SHARED_PALLET, shape.robots))
    for pose, robots in zones:
        def there(robot: str, pose: str = pose) -> Predicate:
            return any_of(f"{robot}.pos_m == {pose}", f"{robot}.ref_pos_c == {pose}")
        pairs = [(a, b) for n, a in enumerate(robots) for b in robots[n + 1:]]
        specifications.append(forbid(f"two_robots_at_{pose}", any_of(*(there(a) & there(b) for a, b in pairs))))
    for feeder in shape.feeders:
        if feeder.timing is not SensorTiming.GUARDED:
            continue
        for robot in feeder.robots:
            # Sent away while the sensor's effect is due: the effect would be lost.
            specifications.append(forbid(
                f"{robot}_sent_from_{feeder.name}_before_its_sensor",
                all_of(f"{robot}.pos_m == {feeder.pose}", f"{robot}.ref_pos_c != {feeder.pose}",
                       f"{gripper_of(robot)}.vac_m", f"{feeder.name}.present_m", f"!{feeder.name}.feed_c")))
    return specifications
