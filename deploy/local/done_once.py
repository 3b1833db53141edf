"""Was every operation of a `hubctl up` run done exactly once? Read from the run's recordings.

Each controller start records into a file of its own, so a run whose controller was restarted has
several; read together in the order they began, they say what the controller did over the whole
run. An operation's finish counts once: finishing again without a recorded reset in between
(`finished -> initial`, the console's reset or an order's end) is a redone operation, the failure a
controller restart must never cause. A restarted controller restores the operation states it persisted
(a `restore` record); announcing an operation it restored as finished is no new finish. Restoring one
as initial that was counted finished is a reset: an order's end, which the order book commits with the
product's reset (controller/production/book.py), by a controller killed before it recorded the reset.

An operation finished once may still have been done twice by the devices (a restarted controller that
re-sent the nutrunner's start). So the physical work is counted too, from the measured values and commands
the recordings hold (`WorkCount`): each tracking ability of the model that sets a product variable from
the devices' conditions (torque while the robot holds the nutrunner at bolt 7, the filter tool on filter
2) is a piece of work, done each time its conditions become true; each must be done at most once per
order. Work done while no controller recorded (between a kill and the restart's first tick) is counted
when the restarted controller first finds it, unless the killed one had seen it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.model import And, Eq, Kind, Model, OperationState, Predicate, Ref, Value, all_of
from common.stations import load_model
from common.wire.ctl import OrderStarted
from controller.recording.reader import Record, list_runs, open_run
from controller.recording.schema import (
    CommandRecord,
    HubState,
    OperationRecord,
    RecordKind,
    RestoreRecord,
    StateRecord,
)
from controller.recording.writer import recording_dir

from .recordings import recording_settings

OPERATION_PREFIX = "op."  # operation states among the persisted (restored) values
FINISHED, INITIAL = OperationState.FINISHED.value, OperationState.INITIAL.value
WORK_KINDS = frozenset({RecordKind.EVENT, RecordKind.TICK, RecordKind.STATE, RecordKind.COMMAND, RecordKind.RESTORE})


def run_recordings(config_path: str, station: str, started: float) -> list[Path]:
    """The recordings of `station` begun at or after `started` (wall clock), oldest first: one per controller
    start of the run."""
    directory = recording_dir(recording_settings(config_path).dir)
    return [r.path for r in list_runs(directory)
            if not r.problem and r.meta.started >= started and r.meta.station == station]


@dataclass
class DoneOnce:
    recordings: list[Path]
    finishes: dict[str, int] = field(default_factory=dict)  # operation -> finishes recorded
    resets: dict[str, int] = field(default_factory=dict)  # operation -> finished -> initial recorded
    # Finishes known only from a restarted controller's restored state: the killed controller's last records, not yet
    # handed to its recording's writer, died with it.
    restored_only: set[str] = field(default_factory=set)
    work: WorkCount | None = None  # the physical work, when the run's model could be loaded
    work_note: str = ""  # why it was not counted

    def redone(self) -> dict[str, int]:
        """Operations finished more often than reset plus once, with their finishes."""
        return {op: n for op, n in self.finishes.items() if n > self.resets.get(op, 0) + 1}

    def text(self) -> str:
        files = f"{len(self.recordings)} recording{'s' if len(self.recordings) != 1 else ''}"
        redone = self.redone()
        if redone:
            listed = ", ".join(f"{op} {n} times" for op, n in sorted(redone.items()))
            return f"REDONE, from {files}: {listed}"
        if self.work is not None and self.work.redone():
            return f"from {files}: {self.work.text()}"
        if not self.finishes:
            return f"from {files}: no operation finished"
        restored = (f" ({len(self.restored_only)} known from a restarted controller's restored state: "
                    f"{', '.join(sorted(self.restored_only))})") if self.restored_only else ""
        return f"from {files}: each of {len(self.finishes)} finished operations finished once{restored}" + \
            (f"; {self.work.text()}" if self.work is not None else f"; {self.work_note}" if self.work_note else "")

    def failed(self) -> bool:
        """An operation finished again, or a piece of physical work done twice in one order."""
        return bool(self.redone()) or (self.work is not None and bool(self.work.redone()))


def check_done_once(recordings: list[Path], model: Model | None = None) -> DoneOnce:
    """Operations and physical work over `recordings` (oldest first); `model`: the run's (default: loaded from
    the first recording's meta; the work is not counted if it cannot be)."""
    result = DoneOnce(list(recordings))
    requested: list[str] = []
    for index, path in enumerate(recordings):
        with open_run(path) as run:
            if index == 0:
                requested = list(run.meta.requested)
                model, result.work_note = _model_of(model, run.meta.model)
                result.work = None if model is None else WorkCount(model, work_items(model))
            count_finishes(run.events(kinds={RecordKind.OPERATION, RecordKind.RESTORE}), result)
            if result.work is not None:
                result.work.count(run.events(kinds=WORK_KINDS))
    if result.work is not None:
        result.work.finish(requested)
    return result


def _model_of(model: Model | None, reference: str) -> tuple[Model | None, str]:
    if model is not None:
        return model, ""
    try:
        return load_model(reference), ""
    except Exception as exc:  # any error of the station's own code: the operations are still counted
        return None, f"physical work not counted: model {reference!r} does not load ({type(exc).__name__}: {exc})"


def count_finishes(records: Iterable[Record], into: DoneOnce) -> None:
    """Add one controller's `operation` and `restore` records (one recording, in order) to `into`."""
    counter = FinishCounter(into)
    for record in records:
        counter.add(record)


class FinishCounter:
    """One controller's `operation` and `restore` records, added one at a time (in order) to a `DoneOnce`."""

    def __init__(self, into: DoneOnce) -> None:
        self.into = into
        # What this controller knew: only what it restored, not what the one before it did (a controller that lost
        # its state and finished an operation again redid it).
        self.state: dict[str, str] = {}

    def add(self, record: Record) -> None:
        data, into, state = record.data, self.into, self.state
        if isinstance(data, RestoreRecord):
            for key, value in data.values.items():
                if key.startswith(OPERATION_PREFIX):
                    op = key.removeprefix(OPERATION_PREFIX)
                    first_seen = op not in state  # this controller's start-up restore, not an order's values
                    state[op] = str(value)
                    finishes, resets = into.finishes.get(op, 0), into.resets.get(op, 0)
                    if state[op] == FINISHED and finishes == resets:
                        into.finishes[op] = finishes + 1
                        into.restored_only.add(op)
                    elif state[op] == INITIAL and first_seen and finishes > resets:
                        into.resets[op] = resets + 1
        elif isinstance(data, OperationRecord):
            op = record.key
            if data.after == FINISHED and state.get(op) != FINISHED:
                into.finishes[op] = into.finishes.get(op, 0) + 1
            elif data.before == FINISHED and data.after == INITIAL:
                into.resets[op] = into.resets.get(op, 0) + 1
            state[op] = data.after


# --- physical work: what the devices did, not only what the controller concluded -----------------------

NO_ORDER = 0  # the work of a run without orders (every operation once), or before its first order


@dataclass(frozen=True)
class WorkItem:
    """A piece of physical work a tracking ability sees done: `seen` (its guard's conditions on measured and
    command variables, e.g. torque on the nutrunner while the robot holds it at bolt 7) becoming true; the
    ability then writes `value` into the product's `path`."""

    name: str
    seen: Predicate
    path: str
    value: Value


def work_items(model: Model) -> tuple[WorkItem, ...]:
    """The model's tracking abilities that set one product variable from devices' conditions."""
    estimated = set(model.paths_of_kind(Kind.ESTIMATED))
    items = []
    for ability in model.tracking:
        (transition,) = ability.transitions
        guard = transition.guard
        conditions = [p for p in (guard.items if isinstance(guard, And) else (guard,)) if not p.paths() & estimated]
        writes = [(a.path, a.value) for a in transition.actions if a.path in estimated]
        if not conditions or len(writes) != 1:
            continue
        path, value = writes[0]
        if not isinstance(value, Ref):  # a value copied from another variable is no product state of its own
            items.append(WorkItem(ability.name, all_of(*conditions), path, value))
    return tuple(items)


def work_asked(model: Model, items: Iterable[WorkItem], operations: Iterable[str]) -> frozenset[str]:
    """The work items whose result a goal of `operations` asks for (`path == value` among its conditions)."""
    asked = set()
    for name in operations:
        goal = model.operation_by_name[name].goal
        wanted = {(p.path, p.value) for p in (goal.items if isinstance(goal, And) else (goal,)) if isinstance(p, Eq)}
        asked |= {item.name for item in items if (item.path, item.value) in wanted}
    return frozenset(asked)


@dataclass
class WorkCount:
    """Rising edges of each work item's conditions per order, over the recordings of a run read in order."""

    model: Model
    items: tuple[WorkItem, ...]
    seen: dict[tuple[int, str], int] = field(default_factory=dict)  # (order, item) -> times done
    asked: dict[int, frozenset[str]] = field(default_factory=dict)  # order -> the work its operations ask for
    holding: dict[str, bool] = field(default_factory=dict)  # item -> its conditions held, over restarts
    order: int = NO_ORDER  # the order on the station as the last recording read left it

    def redone(self) -> dict[tuple[int, str], int]:
        return {key: n for key, n in self.seen.items() if n > 1}

    def missed(self) -> list[tuple[int, str]]:
        """Work an order asked for that no recording saw done (it may have happened while no controller ran)."""
        return [(order, item) for order, names in self.asked.items() for item in sorted(names)
                if not self.seen.get((order, item))]

    def count(self, records: Iterable[Record]) -> None:
        """One controller's recording, in order. Its values start at the model's initial ones (the controller
        records what changed from them); until its first tick they are being taken in (persisted state, the
        hubs' states and mirrors), so the conditions are looked at then first: one that holds and did not
        hold at the previous controller's end is work done while no controller recorded it, counted once."""
        self.begin()
        for record in records:
            self.add(record)
        self.settle()

    def begin(self) -> None:
        """A controller's recording starts: `add` its records, in order, then `settle`."""
        self._values: dict[str, Value] = dict(self.model.initial_state())
        self._by_path: dict[str, list[WorkItem]] = {}
        for item in self.items:
            for path in item.seen.paths():
                self._by_path.setdefault(path, []).append(item)
        self._ticked = False
        self._instant: float | None = None  # of the hubs' states taken in so far and not looked at
        self._touched: dict[str, WorkItem] = {}

    def add(self, record: Record) -> None:
        data, values = record.data, self._values
        # The hubs' states a controller took in at one tick are one instant: the order they are recorded in is
        # not the order they happened in (a nutrunner's torque gone and the dock seeing it leave, in one tick,
        # are no moment of torque outside the dock). Their conditions are looked at once all of them are in.
        if self._instant is not None and not (record.kind is RecordKind.STATE and record.t == self._instant):
            self.settle()
        if isinstance(data, OrderStarted):
            self.order = data.order
            operations = self.model.variant_by_name[data.variant].requested(self.model.operations)
            self.asked[data.order] = work_asked(self.model, self.items, operations)
        elif record.kind is RecordKind.TICK and not self._ticked:
            self._ticked = True
            self._look(self.items, values)
        elif isinstance(data, StateRecord | CommandRecord | RestoreRecord) and data.values:
            values.update(data.values)
            if self._ticked:
                self._touched.update((item.name, item) for path in data.values for item in self._by_path.get(path, ()))
                if record.kind is RecordKind.STATE:
                    self._instant = record.t
                else:
                    self.settle()

    def settle(self) -> None:
        """Look at the conditions the records added since the last look touched."""
        touched, self._touched, self._instant = self._touched, {}, None
        self._look(touched.values(), self._values)

    def _look(self, items: Iterable[WorkItem], values: Mapping[str, Value]) -> None:
        for item in items:
            now = item.seen.eval(values)
            if now and not self.holding.get(item.name, False):
                self.seen[self.order, item.name] = self.seen.get((self.order, item.name), 0) + 1
            self.holding[item.name] = now

    def finish(self, requested: Iterable[str]) -> None:
        """A run that started no order asked for the work of the operations it requested."""
        if not self.asked:
            self.asked[NO_ORDER] = work_asked(self.model, self.items, requested)

    def text(self) -> str:
        redone, missed = self.redone(), self.missed()
        if redone:
            return "physical work REDONE: " + ", ".join(
                f"{item} {n} times in order {order}" for (order, item), n in sorted(redone.items()))
        done = sum(1 for n in self.seen.values() if n)
        text = f"physical work ({len(self.items)} tracked kinds): {done} pieces, none done twice in an order"
        if missed:
            text += (f"; {len(missed)} not seen (done while no controller recorded): "
                     + ", ".join(f"{item} of order {order}" for order, item in missed[:5])
                     + (" ..." if len(missed) > 5 else ""))
        return text


class DoneOnceSink:
    """A run's recording sink (controller/recording/hooks.py) that keeps nothing but the counts: each operation's
    finishes and resets and the physical work per order, as the records come, so a run of hundreds of orders in
    process is checked as `check_done_once` checks a recorded one, in memory that does not grow with the orders."""

    def __init__(self, model: Model) -> None:
        self.done = DoneOnce([])
        self._finishes = FinishCounter(self.done)
        self.work = self.done.work = WorkCount(model, work_items(model))
        self.work.begin()
        self._requested: list[str] = []

    def put(self, t: float, kind: RecordKind, key: str, data: Any) -> None:
        record = Record(t, kind, key, data)
        if kind in (RecordKind.OPERATION, RecordKind.RESTORE):
            self._finishes.add(record)
        if kind in WORK_KINDS:
            self.work.add(record)

    def ingested(self, t: float, changed: dict[str, Value], hub_states: Sequence[HubState]) -> None:
        if changed:
            self.work.add(Record(t, RecordKind.STATE, "", StateRecord(values=dict(changed))))

    def update_meta(self, **fields: Any) -> None:
        requested = fields.get("requested")
        if requested is not None:
            self._requested = list(requested)

    def close(self) -> None:
        self.work.settle()
        self.work.finish(self._requested)
