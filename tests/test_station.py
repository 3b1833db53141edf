"""The reference station and the synthetic benchmark station.

The explicit-state helper below searches breadth-first over the model's deliberate,
automatic and effect transitions, with the engine's semantics: automatic transitions
are urgent (they fire to a fixpoint after every step), effects may take any of their
outcomes, and no step may enter a forbidden state. It is not a planner: it only
answers "is this goal reachable from here", and keeps that cheap by searching over the
resources an operation touches.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import msgspec
import pytest

from common.model import (
    Ability,
    Kind,
    Model,
    ModelError,
    OperationState,
    Predicate,
    Ref,
    Transition,
    TransitionKind,
    Value,
    all_of,
    apply_all,
    operation,
)
from common.resources.ur import neighbours
from common.stations import engine_assembly
from tests.stations import synthetic

State = dict[str, Value]


# --- explicit-state helper -------------------------------------------------------------
@dataclass(frozen=True)
class Found:
    steps: tuple[str, ...]  # transition names, automatic ones included
    state: State


class Explorer:
    """Breadth-first reachability over a subset of a model's ability transitions.

    `abilities` are searched (all of the model's, tracking included, by default).
    `followers` are sensors that only observe the others (the dock, the camera): their
    effects fire at once, like automatic transitions, so that they stay consistent
    without multiplying the interleavings.
    """

    def __init__(self, model: Model, abilities: Iterable[Ability] | None = None,
                 followers: Iterable[Ability] = ()) -> None:
        self.model = model
        chosen = list(model.abilities if abilities is None else abilities)
        transitions = list(dict.fromkeys(t for a in chosen for t in a.transitions))
        reactions = [t for a in followers for t in a.transitions if t not in transitions]
        self.automatic = [t for t in transitions if t.kind is TransitionKind.AUTOMATIC] + reactions
        self.steps = [t for t in transitions if t.kind is not TransitionKind.AUTOMATIC]
        self.effects = [t for t in transitions if t.kind is TransitionKind.EFFECT]
        transitions += reactions
        self.forbidden = [(s.name, s.forbidden) for s in model.specifications]
        # A step from an allowed state can only violate a specification over what it writes.
        self.checks = {t.name: [(name, f) for name, f in self.forbidden if f.paths() & t.written()]
                       for t in transitions}
        written = {p for t in transitions for p in t.written()}
        self.key_paths = tuple(sorted(written))

    def violated(self, state: Mapping[str, Value], after: Transition | None = None) -> str | None:
        """The first specification the state violates (only those `after` can affect, if given)."""
        checks = self.forbidden if after is None else self.checks[after.name]
        return next((name for name, forbidden in checks if forbidden.eval(state)), None)

    def urgent(self, state: State, trace: list[str]) -> State | None:
        """Fire automatic transitions (and followers) until none is enabled; None if that enters a forbidden state."""
        for _ in range(1000):
            enabled = next((t for t in self.automatic if t.guard.eval(state)), None)
            if enabled is None:
                return state
            state = apply_all(enabled.actions, state)
            trace.append(enabled.name)
            if self.violated(state, enabled):
                return None
        raise AssertionError(f"automatic transitions do not settle; last: {trace[-5:]}")

    def successors(self, state: State) -> Iterable[tuple[list[str], State]]:
        for t in self.steps:
            if not t.guard.eval(state):
                continue
            for outcome in t.outcomes:
                after = apply_all(outcome, state)
                if self.violated(after, t):
                    continue
                trace = [t.name]
                settled = self.urgent(after, trace)
                if settled is not None:
                    yield trace, settled

    def reach(self, start: State, goal: Predicate, limit: int = 200_000) -> Found | None:
        trace: list[str] = []
        assert self.violated(start) is None, f"the start state is forbidden: {self.violated(start)}"
        first = self.urgent(dict(start), trace)
        assert first is not None, f"automatic transitions from the start enter a forbidden state: {trace}"
        parents: dict[tuple[Value, ...], tuple[tuple[Value, ...] | None, list[str], State]] = {
            self.key(first): (None, trace, first)}
        queue = deque([first])
        while queue:
            state = queue.popleft()
            if goal.eval(state):
                return Found(self._path(self.key(state), parents), state)
            for trace, after in self.successors(state):
                key = self.key(after)
                if key not in parents:
                    parents[key] = (self.key(state), trace, after)
                    queue.append(after)
            assert len(parents) < limit, f"search gave up after {len(parents)} states"
        return None

    def settle(self, state: State) -> State:
        """Let the world finish: apply effects (first outcome) and automatics until nothing is enabled."""
        for _ in range(1000):
            trace: list[str] = []
            settled = self.urgent(state, trace)
            assert settled is not None, f"settling entered a forbidden state after {trace}"
            state = settled
            enabled = next((t for t in self.effects if t.guard.eval(state)), None)
            if enabled is None:
                return state
            state = apply_all(enabled.actions, state)
            assert not self.violated(state), f"{enabled.name} entered forbidden state {self.violated(state)}"
        raise AssertionError("effects do not settle")

    def key(self, state: Mapping[str, Value]) -> tuple[Value, ...]:
        return tuple(state[p] for p in self.key_paths)

    @staticmethod
    def _path(key: tuple[Value, ...], parents: Mapping) -> tuple[str, ...]:
        steps: list[str] = []
        current: tuple[Value, ...] | None = key
        while current is not None:
            parent, trace, _ = parents[current]
            steps[:0] = trace
            current = parent
        return tuple(steps)


def relevant_abilities(model: Model, goal: Predicate) -> list[Ability]:
    """The abilities an operation needs, to keep the search small (what it finds is still a real path).

    The resources that the goal reads, or that the transitions writing the goal's
    variables read; of those, an ability that sets an enumerated command which those
    transitions compare with particular values (`human.instr_c == lift_frame`) only if
    it sets one of those values: sending the operator to another task cannot help.
    Tracking abilities take part when they write what the goal or those transitions
    read; the others only record (another bolt tightened on the way) and would only
    multiply the states.
    """
    goal_paths = goal.paths()
    writers = [t for t in model.ability_transitions if t.written() & goal_paths]
    paths = goal_paths | {p for t in writers for p in t.read()}
    resources = {r.name for r in map(model.resource_of, paths) if r is not None}
    wanted: dict[str, set[Value]] = {}
    for t in writers:
        for path, value in t.guard.operands():
            variable = model.var(path)
            if variable.kind is Kind.COMMAND and not variable.domain.is_bool and not isinstance(value, Ref):
                wanted.setdefault(path, set()).add(value)

    def useful(a: Ability) -> bool:
        sets = [(x.path, x.value) for t in a.transitions if t.kind is TransitionKind.DELIBERATE for x in t.actions]
        return all(path not in wanted or value in wanted[path] for path, value in sets)

    needed = [a for r in model.resources if r.name in resources for a in r.abilities if useful(a)]
    return needed + [a for a in model.tracking if any(t.written() & paths for t in a.transitions)]


def followers(model: Model) -> list[Ability]:
    """Abilities of resources with no commands whose effects react to other resources (dock, camera)."""
    return [a for r in model.resources if not r.commands for a in r.abilities
            if any(model.resource_of(p) is not r for t in a.transitions for p in t.read())]


def abilities_of(model: Model, *resources: str) -> list[Ability]:
    return [a for name in resources for a in model.resource_by_name[name].abilities]


def fire(transition: Transition, state: State) -> State:
    assert transition.guard.eval(state), f"{transition.name} is not enabled: {transition.guard}"
    return apply_all(transition.actions, state)


# --- the reference station -------------------------------------------------------------
@pytest.fixture(scope="module")
def station() -> Model:
    return engine_assembly.build_model()


def test_station_builds_without_problems(station: Model) -> None:
    assert station.problems() == []
    assert {r.name for r in station.resources} == {
        "agv", "mir", "rfid", "human", "cam", "ur", "rsp", "dock", "nr", "lift"}
    assert [op.name for op in station.operations] == list(engine_assembly.OPERATION_ORDER)


def test_station_has_24_bolts_with_tracking(station: Model) -> None:
    assert engine_assembly.BOLT_COUNT == 24
    bolts = [p for p in station.variables if p.startswith("engine.bolt")]
    assert len(bolts) == 24
    tracked = {t.written().pop() for a in station.tracking for t in a.transitions}
    assert set(bolts) <= tracked
    bolt7 = next(a for a in station.tracking if a.name == "engine.bolt7_tightened")
    assert {"nr.tqr_m", "ur.pos_m", "engine.bolt7_e"} <= bolt7.transitions[0].read()
    for i in engine_assembly.BOLTS:
        op = station.operation_by_name[f"TightenBolt{i}"]
        assert str(op.goal) == f"engine.bolt{i}_e == tightened"
    assert len([op for op in station.operations if op.name.startswith("MountFilter")]) == engine_assembly.FILTER_COUNT


def ur_neighbours(model: Model) -> dict[str, tuple[str, ...]]:
    """The robot's pose graph, from the poses and moves its resource was built with."""
    parameters = model.resource_by_name["ur"].parameters
    return neighbours(msgspec.convert(parameters["poses"], list[str]),
                      msgspec.convert(parameters["allowed_moves"], list[tuple[str, str]]))


def test_bolt_poses_form_a_ring_around_above_engine(station: Model) -> None:
    graph = ur_neighbours(station)
    for i in engine_assembly.BOLTS:
        ring = {f"at_bolt{i % 24 + 1}", f"at_bolt{(i - 2) % 24 + 1}"}
        assert set(graph[f"at_bolt{i}"]) == ring | {"above_engine"}


def test_a_misspelled_variable_is_reported_with_its_path(station: Model) -> None:
    broken = operation("TightenBolt99", "engine.bolt7_e == placed", "engine.bolt7e == tightened")
    with pytest.raises(ModelError) as raised:
        Model("broken", station.resources, station.estimated, station.tracking,
              (*station.operations, broken), station.specifications)
    assert "unknown variable engine.bolt7e" in str(raised.value)
    assert "TightenBolt99" in str(raised.value)


def test_a_value_outside_a_domain_is_reported(station: Model) -> None:
    broken = operation("Broken", True, "engine.frame_e == upside_down")
    with pytest.raises(ModelError, match="upside_down"):
        Model("broken", station.resources, station.estimated, station.tracking, (broken,))


def test_initial_state_is_allowed(station: Model) -> None:
    state = station.initial_state()
    assert [s.name for s in station.specifications if s.forbidden.eval(state)] == []


@pytest.mark.slow
def test_each_operation_reaches_its_goal_in_order(station: Model) -> None:
    """Run the operations one after the other: each precondition holds when its turn
    comes, and its goal is reachable without entering a forbidden state."""
    state = station.initial_state()
    for name in engine_assembly.OPERATION_ORDER:
        op = station.operation_by_name[name]
        assert op.pre.eval(state), f"{name}: precondition {op.pre} does not hold after the operations before it"
        state = fire(op.start_transition(), state)
        explorer = Explorer(station, relevant_abilities(station, op.goal), followers(station))
        assert explorer.violated(state) is None, f"starting {name} enters {explorer.violated(state)}"
        found = explorer.reach(state, op.goal)
        assert found is not None, f"{name}: goal {op.goal} is unreachable"
        state = explorer.settle(fire(op.finish_transition(), found.state))
    assert all(state[f"op.{name}"] == OperationState.FINISHED for name in engine_assembly.OPERATION_ORDER)


def test_neighbouring_bolts_are_tightened_along_the_ring(station: Model) -> None:
    """From above the engine with the nutrunner, neighbouring bolts are tightened along the ring, one move each."""
    state = station.initial_state() | {
        "engine.frame_e": "placed", "rsp.tool_m": "nutrunner", "rsp.lock_c": True, "rsp.locked_m": True,
        "dock.nutrunner_home_m": False, "ur.pos_m": "above_engine", "ur.ref_pos_c": "above_engine",
        **{engine_assembly.bolt(i): "placed" for i in (1, 2, 3)},
    }
    # Three neighbouring bolts keep the breadth-first search small; the ring makes the shortest tour obvious.
    goal = all_of(*(f"{engine_assembly.bolt(i)} == tightened" for i in range(1, 4)))
    bolt_tracking = [a for a in station.tracking if a.name in {f"engine.bolt{i}_tightened" for i in (1, 2, 3)}]
    found = Explorer(station, [*abilities_of(station, "ur", "nr"), *bolt_tracking]).reach(state, goal)
    assert found is not None
    moves = [s for s in found.steps if s.startswith("ur.") and s.endswith(".enabled")]
    assert moves == ["ur.move_to_at_bolt1.enabled", "ur.move_to_at_bolt2.enabled", "ur.move_to_at_bolt3.enabled"] \
        or moves == ["ur.move_to_at_bolt3.enabled", "ur.move_to_at_bolt2.enabled", "ur.move_to_at_bolt1.enabled"]


ALLOWED = {"rfid.verified_m": True}
NUTRUNNER_ON_ROBOT = {"rsp.lock_c": True, "rsp.locked_m": True, "rsp.tool_m": "nutrunner",
                      "dock.nutrunner_home_m": False}


@pytest.mark.parametrize(("changes", "violated"), [
    (ALLOWED | {"human.instr_c": "tighten_pipe1", "ur.ref_pos_c": "above_engine"},
     "robot_moves_in_shared_zone_while_operator_sent_to_robot_zone"),
    (ALLOWED | {"human.instr_c": "tighten_pipe1", "ur.ref_pos_c": "at_bolt3", "ur.pos_m": "unknown"},
     "robot_moves_in_shared_zone_while_operator_sent_to_robot_zone"),
    (ALLOWED | {"cam.zone_m": "robot", "ur.ref_pos_c": "home", "ur.pos_m": "unknown"},
     "robot_moves_in_shared_zone_while_operator_seen_in_robot_zone"),
    (ALLOWED | {"human.instr_c": "place_bolts", "ur.ref_pos_c": "above_engine"}, None),  # shared: collaborative
    (ALLOWED | {"human.instr_c": "tighten_pipe1", "ur.ref_pos_c": "above_engine", "ur.pos_m": "above_engine"},
     None),  # standing still
    ({"human.instr_c": "place_bolts"}, "operator_instructed_before_verified"),
    ({"op.PlaceBolts": OperationState.EXECUTING}, "operator_operation_before_verified"),
    ({"op.AttachLiftTool": OperationState.EXECUTING}, None),  # robot-only operations run unverified
    (NUTRUNNER_ON_ROBOT | {"rsp.lock_c": False, "ur.pos_m": "home"}, "tool_released_outside_its_slot"),
    (NUTRUNNER_ON_ROBOT | {"rsp.lock_c": False, "ur.pos_m": "dock_nutrunner", "ur.ref_pos_c": "dock_nutrunner"},
     None),
    (NUTRUNNER_ON_ROBOT | {"nr.run_c": True, "nr.run_m": True, "ur.pos_m": "unknown", "ur.ref_pos_c": "at_bolt1"},
     "robot_moves_while_its_nutrunner_runs"),
])
def test_specifications(station: Model, changes: dict[str, Value], violated: str | None) -> None:
    state = station.initial_state() | changes
    assert [s.name for s in station.specifications if s.forbidden.eval(state)] == ([violated] if violated else [])


# --- the synthetic station -------------------------------------------------------------
@pytest.mark.parametrize(("bolts", "poses"), [(0, 1), (1, 1), (5, 2), (24, 10), (100, 10)])
def test_synthetic_station_builds(bolts: int, poses: int) -> None:
    model = synthetic.build_model(bolts, poses)
    assert len([p for p in model.variables if p.startswith("engine.bolt")]) == bolts
    assert [op.name for op in model.operations] == [f"TightenBolt{i}" for i in range(1, bolts + 1)]
    assert len(model.tracking) == bolts


def test_synthetic_ring_and_bolt_poses() -> None:
    model = synthetic.build_model(12, 5)
    graph = ur_neighbours(model)
    assert graph["p0"] == ("p1", "p4")
    assert graph["p3"] == ("p2", "p4")
    tracking = {a.name: a for a in model.tracking}
    assert "ur.pos_m == p2" in str(tracking["engine.bolt7_tightened"].transitions[0].guard)


def test_synthetic_goal_is_reachable() -> None:
    model = synthetic.build_model(3, 4)
    found = Explorer(model).reach(model.initial_state(), model.operation_by_name["TightenBolt3"].goal)
    assert found is not None
    # p0 -> p3 is one move on the ring (backwards), then one tightening.
    assert [s for s in found.steps if s.endswith(".enabled")] == ["ur.move_to_p3.enabled", "nr.tighten.enabled"]
