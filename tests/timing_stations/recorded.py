"""A recording sink for the timing tests: plan requests, events and operation changes, with their station time."""

from __future__ import annotations

from collections import Counter
from typing import Any

import msgspec

from common.model import OperationState
from common.wire.ctl import Livelock
from controller.recording.schema import OperationRecord, PlanRequestRecord, RecordKind


class Recorded:
    """A recording sink keeping what the properties look at: plan requests, events and operation changes."""

    def __init__(self) -> None:
        self.requests: list[tuple[float, PlanRequestRecord]] = []
        self.events: list[tuple[float, msgspec.Struct]] = []
        self.operations: list[tuple[float, str, OperationRecord]] = []  # (time, operation, change)

    def put(self, t: float, kind: RecordKind, key: str, data: msgspec.Struct) -> None:
        if kind is RecordKind.PLAN_REQUEST:
            assert isinstance(data, PlanRequestRecord)
            self.requests.append((t, data))
        elif kind is RecordKind.EVENT:
            self.events.append((t, data))
        elif kind is RecordKind.OPERATION:
            assert isinstance(data, OperationRecord)
            self.operations.append((t, key, data))

    def ingested(self, t: float, changed: dict[str, Any], hub_states: Any) -> None:
        pass

    def update_meta(self, **fields: Any) -> None:
        pass

    def close(self) -> None:
        pass

    def most_requests_from_one_state(self) -> int:
        counts = Counter((tuple(r.goals), r.start) for _, r in self.requests if r.goals)
        return max(counts.values(), default=0)

    def livelocks(self) -> list[tuple[float, Livelock]]:
        return [(t, e) for t, e in self.events if isinstance(e, Livelock)]

    def final_states(self) -> dict[str, OperationState]:
        return {operation: OperationState(change.after) for _, operation, change in self.operations}
