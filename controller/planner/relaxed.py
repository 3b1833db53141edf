"""The relaxed-plan heuristic (FF) over finite-domain values, with preferred moves.

Relaxation: a variable accumulates every value it reaches instead of swapping one for
another, so a relaxed state is one bit mask of reached values per variable. A
predicate (negations pushed to the literals) holds in a relaxed state when some
choice of reached values makes it true, which over-approximates every real state
the masks contain: a goal that is relaxed-unreachable is unreachable, so such a
state is a proven dead end. Synthesized guards are part of the relaxation, so the
operator's leaving the robot zone appears in the relaxed plan that moves the robot.

`RelaxedPlan.evaluate(state)` layers the reachable values from `state` (a guard is
re-evaluated only when a variable it reads gained a value), then extracts a relaxed
plan backwards from the goal, each fact from its earliest achiever: h is the number
of moves in it, and the moves that are applicable in `state` itself are *preferred*,
the ones a satisficing search tries first. Nothing is learned per station: the
model's own guards and actions are all it reads.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from common.model import Predicate
from common.model.compiled import State
from common.model.predicates import And, Const, Eq, In, IsTrue, Ne, Not, Or, Ref

from .abstraction import INF
from .steps import Move, StepSystem

# NNF nodes over (variable index, value mask): ("lit", i, mask) | ("eqv", i, j, equal) |
# ("and", children) | ("or", children) | ("const", bool)
Node = tuple
_IN_STATE = (0, -1)  # a fact of the evaluated state: layer 0, no achiever
APPLIED = 1 << 30  # tested-in-layer mark of an applied relaxed action: never tested again
HELD = -2  # mark of a conjunct that held in an earlier layer: it holds from then on
GOALS_KEPT = 256  # relaxed plans (with their estimates) kept by goal
ESTIMATES_KEPT = 20_000  # estimates kept per goal


@dataclass(frozen=True)
class RelaxedAction:
    move: Move
    guard: Node
    reads: tuple[int, ...]
    conjuncts: tuple[Node, ...]  # the guard's top-level conjuncts
    failing: Callable[[list[int]], list[int]]  # the conjuncts that do not hold in given masks
    constants: tuple[tuple[int, int], ...]  # (variable, the one-bit mask it gains)
    copies: tuple[tuple[int, int], ...]  # (target variable, source variable): target := source


@dataclass(frozen=True)
class Estimate:
    h: int  # INF: the goal is unreachable even relaxed (a proven dead end)
    preferred: frozenset[Move]  # moves of the relaxed plan applicable in the evaluated state


class _Encoder:
    """Predicates to NNF over value masks, and NNF to a generated test over the masks list `r`."""

    def __init__(self, paths: Sequence[str], domains: Sequence[tuple[object, ...]]) -> None:
        self.index = {p: i for i, p in enumerate(paths)}
        self.bits: list[dict[tuple[type, object], int]] = [
            {(type(v), v): 1 << k for k, v in enumerate(values)} for values in domains
        ]
        self.full = [(1 << len(values)) - 1 for values in domains]

    def bit(self, i: int, value: object) -> int:
        return self.bits[i].get((type(value), value), 0)

    def mask(self, i: int, values: Sequence[object]) -> int:
        m = 0
        for v in values:
            m |= self.bit(i, v)
        return m

    def nnf(self, p: Predicate, positive: bool = True) -> Node:
        if isinstance(p, Const):
            return ("const", p.value == positive)
        if isinstance(p, Not):
            return self.nnf(p.operand, not positive)
        if isinstance(p, And | Or):
            conjunction = isinstance(p, And) == positive
            return ("and" if conjunction else "or", tuple(self.nnf(q, positive) for q in p.items))
        if isinstance(p, IsTrue):
            i = self.index[p.path]
            return self._literal(i, self.bit(i, True), positive)
        if isinstance(p, Eq | Ne):
            i = self.index[p.path]
            equal = isinstance(p, Eq) == positive
            if isinstance(p.value, Ref):
                return ("eqv", i, self.index[p.value.path], equal)
            return self._literal(i, self.bit(i, p.value), equal)
        if isinstance(p, In):
            i = self.index[p.path]
            return self._literal(i, self.mask(i, p.values), positive)
        raise TypeError(f"unknown predicate node {p!r}")

    def _literal(self, i: int, mask: int, positive: bool) -> Node:
        return ("lit", i, mask if positive else self.full[i] & ~mask)

    def source(self, node: Node) -> str:
        tag = node[0]
        if tag == "const":
            return repr(node[1])
        if tag == "lit":  # an int mask: true when not 0 (a test's value is only ever used as a truth)
            return f"r[{node[1]}] & {node[2]}"
        if tag == "eqv":
            _, i, j, equal = node
            # Masks of two variables compare bit for bit only over one shared domain; the search never
            # relies on a relaxed test being tight, only on it never being false where a real one holds.
            return "True" if not equal else f"(r[{i}] & r[{j}] or {self.full[i] != self.full[j]})"
        if not node[1]:
            return repr(tag == "and")
        children = node[1]
        if tag == "or":  # literals of one variable in a disjunction test one merged mask (synthesized guards)
            merged: dict[int, int] = {}
            for c in children:
                if c[0] == "lit":
                    merged[c[1]] = merged.get(c[1], 0) | c[2]
            children = [("lit", c[1], merged.pop(c[1])) if c[0] == "lit" else c
                        for c in children if c[0] != "lit" or c[1] in merged]
        joiner = " and " if tag == "and" else " or "
        return "(" + joiner.join(self.source(c) for c in children) + ")"

    def compile(self, node: Node) -> Callable[[list[int]], bool]:
        return eval(f"lambda r: {self.source(node)}")  # generated from the model's own predicates

    def failing(self, conjuncts: Sequence[Node]) -> Callable[[list[int]], list[int]]:
        """One generated function listing the conjuncts that do not hold: the relaxed plan needs
        achievers only for those, and most of a synthesized guard holds where it is asked."""
        return _define(self.failing_source("failing", conjuncts))["failing"]  # type: ignore[return-value]  # compiled by exec: the namespace holds objects

    def failing_source(self, name: str, conjuncts: Sequence[Node]) -> list[str]:
        return _listing(name, ((k, f"not ({self.source(c)})") for k, c in enumerate(conjuncts)))


def _listing(name: str, conditions: Iterable[tuple[int, str]]) -> list[str]:
    """The source of `name(r)`: the numbers whose condition holds, in order."""
    return [f"def {name}(r):", "    out = []", *(f"    if {c}: out.append({k})" for k, c in conditions),
            "    return out"]


def _define(lines: Sequence[str]) -> dict[str, Callable[[list[int]], object]]:
    namespace: dict[str, Callable[[list[int]], object]] = {}
    exec("\n".join(lines), namespace)  # generated from the model's own predicates
    return namespace


def conjuncts_of(node: Node) -> tuple[Node, ...]:
    if node[0] == "and":
        return tuple(c for child in node[1] for c in conjuncts_of(child))
    return (node,)


def _reads(node: Node, into: set[int]) -> set[int]:
    tag = node[0]
    if tag == "lit":
        into.add(node[1])
    elif tag == "eqv":
        into.update(node[1:3])
    elif tag in ("and", "or"):
        for child in node[1]:
            _reads(child, into)
    return into


class RelaxedModel:
    """The relaxed moves of one step system (deliberate, effect outcomes and automatics), built once."""

    def __init__(self, system: StepSystem) -> None:
        compiled = system.compiled
        self.encoder = _Encoder(compiled.paths, [d.values for d in compiled.domains])
        moves = [(t, o) for t, o in system.moves] + [(t, 0) for t in system.automatic]
        guards: dict[int, tuple[Node, tuple[Node, ...]]] = {}  # by transition: its outcomes share the guard
        for t, _ in moves:
            if t.number not in guards:
                guard = self.encoder.nnf(compiled.guard_of(t.source))
                guards[t.number] = (guard, conjuncts_of(guard))
        # Every test in one generated module: one compile instead of hundreds.
        lines = []
        for number, (_guard, conjuncts) in guards.items():
            lines += self.encoder.failing_source(f"failing_{number}", conjuncts)
        # Layer 0 of an evaluation: the automatics whose guard holds (actions after the moves are automatics).
        lines += _listing("automatic_ready", ((len(system.moves) + k, self.encoder.source(guards[t.number][0]))
                                              for k, t in enumerate(system.automatic)))
        namespace = _define(lines)
        actions: list[RelaxedAction] = []
        for t, o in moves:
            guard, conjuncts = guards[t.number]
            constants, copies = [], []
            for action in t.source.outcomes[o]:
                target = compiled.index[action.path]
                if isinstance(action.value, Ref):
                    copies.append((target, compiled.index[action.value.path]))
                else:
                    constants.append((target, self.encoder.bit(target, action.value)))
            reads = _reads(guard, set()) | {source for _, source in copies}
            actions.append(RelaxedAction((t.number, o), guard, tuple(sorted(reads)), conjuncts,
                                         namespace[f"failing_{t.number}"],  # type: ignore[arg-type]  # compiled by exec: the namespace holds objects
                                         tuple(constants), tuple(copies)))
        self.actions = tuple(actions)
        self.readers: list[list[int]] = [[] for _ in compiled.paths]
        # An applied action is never tested again, but its copies must carry every value its sources gain
        # later, or the relaxation would under-approximate and "prove" a reachable goal unreachable.
        self.copy_readers: list[list[int]] = [[] for _ in compiled.paths]
        for a, relaxed in enumerate(actions):
            for i in relaxed.reads:
                self.readers[i].append(a)
            for source in sorted({source for _, source in relaxed.copies}):
                self.copy_readers[source].append(a)
        self.wake = self._wake_functions(guards)
        self.constants: list[tuple[tuple[int, int], ...]] = [relaxed.constants for relaxed in actions]
        self.system = system
        self.automatic_ready: Callable[[list[int]], list[int]] = namespace["automatic_ready"]  # type: ignore[assignment]  # compiled by exec: the namespace holds objects
        self.domains = [d.values for d in compiled.domains]
        # A state's value is always of its variable's domain, so a plain value key is exact here.
        self.value_bits: list[dict[object, int]] = [{v: 1 << k for k, v in enumerate(values)}
                                                    for values in self.domains]
        self._goals: OrderedDict[Predicate, RelaxedPlan] = OrderedDict()
        # Tests of nested nodes, by id; the node is kept beside its test so that its id is never reused.
        self.tests: dict[int, tuple[Node, Callable[[list[int]], bool]]] = {}

    def _wake_functions(self, guards: dict[int, tuple[Node, tuple[Node, ...]]]
                        ) -> list[Callable[[list[int], list[int], list[int], list[int], int, list[int]], None]]:
        """Per variable, one generated call that tests the guards of its readers once a layer gave it a
        value: `wake_i(r, tested, waiting, known, layer, ready)` appends to `ready` each reader whose guard
        now holds.

        Masks only grow during an evaluation, so what held still holds: a guard that failed waits on its
        first failing conjunct (`waiting[a]`, -1 before its first test) and is tested again, from that
        conjunct on, only when a variable that conjunct reads gained a value (`tested[a]`: the layer a was
        last tested in, APPLIED once applied). Synthesized guards share most of their conjuncts (the
        robot's 33 moves the same few kilobytes), so each distinct conjunct is evaluated once a layer at
        most: `known[c]` is HELD once it held, else the layer it last failed in.
        """
        encoder = self.encoder
        ids: dict[str, int] = {}
        lines = []
        for number, (_, conjuncts) in guards.items():
            lines.append(f"def first_failing_{number}(r, k, known, layer):")
            for k, conjunct in enumerate(conjuncts):
                source = encoder.source(conjunct)
                c = ids.setdefault(source, len(ids))
                lines += [f"    if k <= {k} and known[{c}] != {HELD}:",
                          f"        if known[{c}] == layer or not ({source}):",
                          f"            known[{c}] = layer", f"            return {k}",
                          f"        known[{c}] = {HELD}"]
            lines.append(f"    return {len(conjuncts)}")
        self.distinct_conjuncts = len(ids)
        for i, readers in enumerate(self.readers):
            lines.append(f"def wake_{i}(r, tested, waiting, known, layer, ready):")
            for a in readers:
                number = self.actions[a].move[0]
                conjuncts = guards[number][1]
                waits_on_i = (-1, *(k for k, c in enumerate(conjuncts) if i in _reads(c, set())))
                lines += [f"    if tested[{a}] < layer and waiting[{a}] in {waits_on_i!r}:",
                          f"        tested[{a}] = layer",
                          f"        k = first_failing_{number}(r, waiting[{a}], known, layer)",
                          f"        if k == {len(conjuncts)}: ready.append({a})",
                          f"        else: waiting[{a}] = k"]
            lines.append("    return None")
        namespace = _define(lines)
        return [namespace[f"wake_{i}"] for i in range(len(self.readers))]  # type: ignore[misc]  # compiled by exec: the namespace holds objects

    def holds(self, node: Node, masks: list[int]) -> bool:
        found = self.tests.get(id(node))
        if found is None:
            found = self.tests[id(node)] = (node, self.encoder.compile(node))
        return found[1](masks)

    def goal(self, goal: Predicate) -> RelaxedPlan:
        """The heuristic toward `goal`, kept (with its estimates) for the next request that asks it: the
        goal agenda asks the same growing conjunctions again when a goal set is planned again."""
        found = self._goals.get(goal)
        if found is None:
            found = self._goals[goal] = RelaxedPlan(self, goal)
            if len(self._goals) > GOALS_KEPT:
                self._goals.popitem(last=False)
        else:
            self._goals.move_to_end(goal)
        return found


class RelaxedPlan:
    """h^FF and preferred moves toward one goal predicate."""

    def __init__(self, relaxed: RelaxedModel, goal: Predicate) -> None:
        self.relaxed = relaxed
        self.goal_node = relaxed.encoder.nnf(goal)
        self.goal_test = relaxed.encoder.compile(self.goal_node)
        self.goal_conjuncts = conjuncts_of(self.goal_node)
        self.goal_failing = relaxed.encoder.failing(self.goal_conjuncts)
        self.evaluations = 0
        self._estimates: dict[State, Estimate] = {}

    def __call__(self, state: State) -> int:
        return self.evaluate(state).h

    def evaluate(self, state: State) -> Estimate:
        estimate = self._estimates.get(state)
        if estimate is None:
            if len(self._estimates) >= ESTIMATES_KEPT:  # memory stays bounded in a long run
                self._estimates.clear()
            estimate = self._estimates[state] = self._evaluate(state)
        return estimate

    def _evaluate(self, state: State) -> Estimate:
        self.evaluations += 1
        relaxed = self.relaxed
        actions = relaxed.actions
        value_bits = relaxed.value_bits
        r = list(map(dict.__getitem__, value_bits, state))
        own = list(r)
        # fact (variable, bit) -> (layer, achieving action or -1 for the state itself); a bit is in r exactly
        # when its fact is known
        facts: dict[tuple[int, int], tuple[int, int]] = dict.fromkeys(enumerate(r), _IN_STATE)
        applied: dict[int, int] = {}  # action -> the layer whose masks made its guard hold
        goal_test = self.goal_test
        layer = 0
        # Layer 0 is the state itself, where the relaxed tests are the real guards: the step system's
        # one generated call finds the enabled deliberate and effect moves (action ids are move indices).
        ready = relaxed.system.enabled_positions(state) + relaxed.automatic_ready(r)
        wake, constants = relaxed.wake, relaxed.constants
        tested = [-1] * len(actions)
        waiting = [-1] * len(actions)
        known = [-1] * relaxed.distinct_conjuncts
        changed: set[int] = set()
        copy_readers = relaxed.copy_readers
        recopy: list[int] = []  # applied actions whose copy sources gained values in the last layer
        while not goal_test(r):
            if layer:
                # Only a guard reading a variable that gained a value can have become true.
                ready = []
                for i in changed:
                    wake[i](r, tested, waiting, known, layer, ready)
                ready.sort()
                recopy = sorted({a for i in changed for a in copy_readers[i] if a in applied})
            if not ready and not recopy:
                return Estimate(INF, frozenset())
            layer += 1
            gained: list[tuple[int, int]] = []
            for a in ready:  # each new fact from its first achiever in action order; r grows after the layer
                applied[a] = layer - 1
                tested[a] = APPLIED
                for fact in constants[a]:
                    if fact not in facts:
                        facts[fact] = (layer, a)
                        gained.append(fact)
            for a in (*ready, *recopy):
                for target, source in actions[a].copies:
                    for bit in self._copied(target, source, r[source]):
                        if (target, bit) not in facts:
                            facts[target, bit] = (layer, a)
                            gained.append((target, bit))
            if not gained:
                return Estimate(INF, frozenset())
            changed = set()
            for i, bit in gained:
                r[i] |= bit
                changed.add(i)
        return self._extract(facts, applied, own, r)

    def _copied(self, target: int, source: int, mask: int) -> list[int]:
        domains, encoder = self.relaxed.domains, self.relaxed.encoder
        return [encoder.bit(target, v) for k, v in enumerate(domains[source]) if mask >> k & 1]

    def _extract(self, facts: dict[tuple[int, int], tuple[int, int]], applied: dict[int, int],
                 own: list[int], reached: list[int]) -> Estimate:
        actions = self.relaxed.actions
        chosen: set[int] = set()
        self._own = own
        self._reached = reached
        self._costs: dict[int, int] = {}
        pending = [f for k in self.goal_failing(own) for f in self._support(self.goal_conjuncts[k], facts)]
        seen: set[tuple[int, int]] = set()
        while pending:
            fact = pending.pop()
            if fact in seen:
                continue
            seen.add(fact)
            achiever = facts[fact][1]
            if achiever < 0 or achiever in chosen:
                continue
            chosen.add(achiever)
            action = actions[achiever]
            for k in action.failing(own):
                pending.extend(self._support(action.conjuncts[k], facts))
            for target, source in action.copies:
                if target == fact[0]:
                    pending.extend(self._copy_support(source, target, fact[1], facts))
        preferred = frozenset(actions[a].move for a in chosen if applied[a] == 0)
        return Estimate(len(chosen), preferred)

    def _copy_support(self, source: int, target: int, bit: int, facts: dict) -> list[tuple[int, int]]:
        encoder, domains = self.relaxed.encoder, self.relaxed.domains
        value = next(v for v in domains[target] if encoder.bit(target, v) == bit)
        wanted = encoder.bit(source, value)
        return [(source, wanted)] if (source, wanted) in facts else []

    # --- the cheapest facts that make a node true (earliest layer; ties: lowest bit) ------------
    def _holds_here(self, node: Node) -> bool:
        """The node holds in the evaluated state itself: it needs no achiever at all."""
        return self.relaxed.holds(node, self._own)

    def _literal_cost(self, i: int, mask: int, facts: dict) -> int:
        reached = mask & self._reached[i]
        if not reached:
            return INF
        if reached & self._own[i]:
            return 0
        return min(facts[i, b][0] for b in _bits(reached))

    def _cost(self, node: Node, facts: dict) -> int:
        if node[0] == "lit":
            return self._literal_cost(node[1], node[2], facts)
        known = self._costs.get(id(node))
        if known is None:
            known = self._costs[id(node)] = self._cost_of(node, facts)
        return known

    def _cost_of(self, node: Node, facts: dict) -> int:
        tag = node[0]
        if tag == "const":
            return 0 if node[1] else INF
        if tag == "eqv":
            return 0 if not node[3] else self._eqv_choice(node, facts)[0]
        if tag == "and":
            worst = 0
            for child in node[1]:
                worst = max(worst, self._cost(child, facts))
                if worst >= INF:
                    break
            return worst
        best = INF
        for child in node[1]:
            best = min(best, self._cost(child, facts))
            if best <= 1:  # nothing cheaper than the first layer once the node does not hold here
                break
        return best

    def _eqv_choice(self, node: Node, facts: dict) -> tuple[int, list[tuple[int, int]]]:
        _, i, j, _ = node
        encoder, domains = self.relaxed.encoder, self.relaxed.domains
        best: tuple[int, list[tuple[int, int]]] = (INF, [])
        for v in domains[i]:
            a, b = (i, encoder.bit(i, v)), (j, encoder.bit(j, v))
            if a in facts and b in facts:
                cost = max(facts[a][0], facts[b][0])
                if cost < best[0]:
                    best = (cost, [a, b])
        return best

    def _support(self, node: Node, facts: dict) -> list[tuple[int, int]]:
        tag = node[0]
        if tag == "const" or (tag == "eqv" and not node[3]):
            return []
        if tag == "lit":
            if node[2] & self._own[node[1]]:
                return []
            i = node[1]
            options = [(facts[i, b][0], b) for b in _bits(node[2] & self._reached[i])]
            return [(i, min(options)[1])] if options else []
        if tag == "eqv":
            return self._eqv_choice(node, facts)[1]
        if self._holds_here(node):
            return []
        if tag == "and":
            return [f for c in node[1] for f in self._support(c, facts)]
        best = min(node[1], key=lambda c: self._cost(c, facts))
        return self._support(best, facts)


def _bits(mask: int) -> list[int]:
    out = []
    while mask:
        low = mask & -mask
        out.append(low)
        mask ^= low
    return out
