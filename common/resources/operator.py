"""The human operator: instructed one task at a time, confirms with a button (smartwatch).

One ability per task T (a template instantiated in a loop):

| predicate | predicate                        | control actions                         | effects                 |
|-----------|----------------------------------|-----------------------------------------|-------------------------|
| enabled   | instr_c == none && !done_m       | instr_c := T (deliberate)               | -                       |
| executing | instr_c == T && !done_m          | -                                       | done_m := T (confirms)  |
| finished  | instr_c == T && done_m           | instr_c := none, records (automatic)    | -                       |
| resetting | instr_c == none && done_m        | -                                       | done_m := F (released)  |

The button release is one effect shared by all tasks (`human.release_button`): one per
task would be the same transition many times over and only widen the planner's search.

`instruct_when[T]` (optional) is when T may be instructed at all (default: whenever the operator is
idle). A station whose tasks must not be asked for again once done says so here; note that a guard
reading the product on the instruction of a task the robot's work follows (placing the bolts,
mounting a filter) made the planner's proofs of "shortest" on tests/bench/bench_planner.py's reference
goal sets go from seconds to not within 90 s, so the reference station sets none.

`confirm_when[T]` is what must physically hold before the operator can finish T (the
operator confirms the ladder frame only once it sits on the engine): a guard on the
confirmation effect. `on_confirm[T]` is what the controller records when T is
confirmed (`engine.bolt1_e := placed`, ...). It is recorded by the same automatic
transition that withdraws the instruction: a separate tracking transition on
`instr_c == T && done_m` would race the withdrawal.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from common.model import Ability, Assign, Domain, Duration, Phase, Resource, ability, command, measured
from common.model.transitions import ActionsLike

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# The operator doing a task, or releasing the button: slower than the robot.
DURATION = Duration.fixed(0.5)
# Releasing the button after the instruction is withdrawn: a thumb lifted, whatever a task takes. A device's
# `delay` in hubs.toml sets how long the operator's tasks take, not this.
RELEASE_DURATION = Duration.fixed(0.5)
RELEASE = "release_button"

NO_TASK = "none"


def operator(name: str = "human", tasks: Sequence[str] = (), confirm_when: Mapping[str, object] | None = None,
             on_confirm: Mapping[str, ActionsLike] | None = None,
             instruct_when: Mapping[str, object] | None = None) -> Resource:
    tasks = tuple(tasks)
    conditions = dict(confirm_when or {})
    records = dict(on_confirm or {})
    instructable = dict(instruct_when or {})
    if NO_TASK in tasks:
        raise ValueError(f"{NO_TASK!r} means no instruction and cannot be a task")
    for parameter, keys in (("confirm_when", conditions), ("on_confirm", records), ("instruct_when", instructable)):
        unknown = set(keys) - set(tasks)
        if unknown:
            raise ValueError(f"{parameter} names tasks {sorted(unknown)} that are not among {tasks}")
    instr_c = command(f"{name}.instr_c", Domain.enum(NO_TASK, *tasks), NO_TASK, "the task the operator is asked to do")
    done_m = measured(f"{name}.done_m", description="the operator pressed the confirm button")
    idle = (instr_c == NO_TASK) & ~done_m
    button_still_held = (instr_c == NO_TASK) & done_m
    abilities: list[Ability] = []
    for task in tasks:
        given = instr_c == task
        abilities.append(ability(
            f"{name}.{task}",
            enabled=Phase(idle, deliberate=f"{instr_c.path} := {task}",
                          guard=instructable.get(task, True)),
            executing=Phase(given & ~done_m, effects=[f"{done_m.path} := true"], guard=conditions.get(task, True)),
            finished=Phase(given & done_m,
                           automatic=[f"{instr_c.path} := {NO_TASK}", *_as_list(records.get(task, ()))]),
            resetting=button_still_held,
        ))
    abilities.append(ability(f"{name}.{RELEASE}",
                             resetting=Phase(button_still_held, effects=[f"{done_m.path} := false"])))
    return Resource(name, (instr_c, done_m), tuple(abilities), device_type="operator",
                    parameters={"tasks": tasks}, ability_durations={RELEASE: RELEASE_DURATION})


def _as_list(actions: ActionsLike) -> list[Assign | str]:
    return [actions] if isinstance(actions, str | Assign) else list(actions)
