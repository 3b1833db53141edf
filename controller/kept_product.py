"""What is done to the product stays done: the finished operations' goals a plan must leave holding.

A plan is asked for the executing operations' goals. Without more, a satisficing plan may reach them by a
detour through work already done: the reference station's first plan for TightenPipe2 once asked the
operator to mount the oil pipes again (to have the nutrunner fetched), which records pipe 1 as `mounted`
over `tightened`. TightenPipe1 was finished, so nothing would ever tighten pipe 1 again, and AgvLeave,
which needs it tightened, waited for ever without a word.

So each request also carries the goals of the finished operations that speak only of the product (the
model's `product` variables; a station that declares none keeps nothing, as before). A plan must reach
them too: a detour that undoes one has to redo it, and the heuristics, which count unreached goals, steer
the search away from undoing it in the first place. A finished goal is kept only while it holds (what a
later operation legitimately changed is not put back) and only if no operation still to run, executing or
requested, names one of its variables in its own goal: that operation moves the variable on (MountOilPipes'
`pipe1 != absent` is not kept while TightenPipe1 is to make it `tightened`).

A kept goal that no plan can reach together with the executing ones is dropped for that request
(controller/planner/policy.py plans again without the kept goals), so keeping never makes a station stall.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

from common.model import Model, OperationState, Predicate, Value
from common.model.compiled import CompiledModel, State


class KeptProduct:
    def __init__(self, compiled: CompiledModel) -> None:
        model: Model = compiled.model
        product = model.product_state
        self._goal_paths = {op.name: frozenset(op.goal.paths()) for op in model.operations}
        # Operations whose goal is about the product alone, with the goal compiled once.
        self._keepable: dict[str, tuple[Predicate, Callable[[Sequence[Value]], bool]]] = {
            op.name: (op.goal, compiled.predicate(op.goal)) for op in model.operations
            if self._goal_paths[op.name] and self._goal_paths[op.name] <= product}
        self._state_index = {op.name: compiled.index[op.state_path] for op in model.operations}

    def goals(self, state: State, still_to_run: Iterable[str]) -> dict[str, Predicate]:
        """The finished operations' product goals a plan from `state` must leave holding; `still_to_run`:
        the operations executing or requested (those finished among them are left out), whose goals move their
        variables on."""
        if not self._keepable:
            return {}
        finished = OperationState.FINISHED.value
        moving: set[str] = set()
        for name in still_to_run:
            if state[self._state_index[name]] != finished:
                moving |= self._goal_paths[name]
        return {name: goal for name, (goal, holds) in self._keepable.items()
                if state[self._state_index[name]] == finished and holds(state)
                and not (self._goal_paths[name] & moving)}
