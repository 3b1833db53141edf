"""An order ends when the devices have let go of its product, not the moment its last operation finishes.

The product's variables are reset when an order ends (controller/production/book.py). An effect that is
enabled and reads them is a device still acting on the product: the operator told to tighten pipe 2, who
confirms once pipe 2 is tightened. Reset the product under it and its condition can never hold again (pipe 2 is
`absent` on the next engine): the instruction stands for ever and the next order's first instruction can never
be given. This was seen over processes: TightenPipe2 finished as the tracking recorded pipe 2 tightened, the
AGV and the MiR left within 0.3 s (speed 4), and the order ended before the operator's confirmation came.

So the order waits while such an effect is enabled, at most `SETTLE_FACTOR` times its duration (at least
`SETTLE_MIN_S`): a device whose hub is gone does not hold the line for ever.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from common.model.compiled import CompiledModel, CompiledTransition, State

SETTLE_FACTOR = 4.0
SETTLE_MIN_S = 2.0


class ProductSettle:
    def __init__(self, compiled: CompiledModel, seconds: Mapping[str, float], clock: Callable[[], float]) -> None:
        indices = frozenset(compiled.index[p] for p in compiled.model.product_state)
        self._effects: tuple[CompiledTransition, ...] = tuple(t for t in compiled.effects if t.reads & indices)
        self._seconds = seconds
        self._clock = clock
        self._since: float | None = None

    def in_hand(self, state: State) -> bool:
        """A device is still acting on the product in `state` (and has not taken too long about it)."""
        acting = [t for t in self._effects if t.guard(state)]
        if not acting:
            self._since = None
            return False
        now = self._clock()
        if self._since is None:
            self._since = now
        bound = max(SETTLE_MIN_S, SETTLE_FACTOR * max(self._seconds.get(t.name, 0.0) for t in acting))
        if now - self._since > bound:
            self._since = None
            return False
        return True
