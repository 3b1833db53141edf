"""An admissible heuristic for a conjunction of goal atoms, built from projections.

The goal is split into atoms (its conjuncts). Two kinds of groups bound the steps left:

* **Conjunction group** (pattern database): a projection that contains the atoms'
  variables; the value is the abstract distance to the conjunction of the atoms.
* **Tour group**: single-variable atoms `x == v` whose variable is read only by their
  own achievers (a bolt's tracking variable). The projection leaves all those
  variables out, so many atoms share it; an atom is reached by firing one of its
  achievers. Every unsatisfied atom j needs a last achievement step; order the atoms
  by it: the segment ending with j's begins at the start or right after the previous
  atom's achievement, and segments are disjoint in time. A segment costs at least the
  abstract distance from where it begins to a state where j's achiever can fire, plus
  that step. So the plan costs at least a shortest Hamiltonian path from the start
  through the atoms, with edge costs `D_j(s)` (from the start) and `W(i, j)` (from
  the states after i's achievers). We bound that path from below: one atom comes
  first, every other atom has its cheapest incoming edge (the lower bound of the design
  note), and a minimum arborescence between *classes* of atoms that behave identically
  in the projection (bolts at one pose) adds the travel between classes. Potentials on
  the states where achievers fire keep work done ahead of time (the robot sent on
  before the tightening ends) from being dropped by both neighbouring segments.

Each family of atoms gets a few projections (its cone up to a cap, then one per
resource the cone left out) and the unit cost of every transition is given to exactly
one of them (zero-one cost partitioning), so all groups add up. Finally no step can
make more than k atoms true, so ceil(unsatisfied / k) is a bound too.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

from common.model import FALSE, TRUE, And, Const, In, Predicate, Ref
from common.model.compiled import CompiledTransition, State, predicate_source

from .abstraction import INF, Abstraction, rename
from .steps import StepSystem
from .stopping import StopTest, check_stop
from .tours import Achiever, TourGroup, generate

DEFAULT_CAP = 12_000  # the largest projection, in abstract states (cold builds grow with it)


def goal_atoms(goals: Iterable[Predicate]) -> list[Predicate]:
    """The conjuncts of the goals, without duplicates or `true`."""
    atoms: list[Predicate] = []

    def add(p: Predicate) -> None:
        if isinstance(p, And):
            for item in p.items:
                add(item)
        elif p != TRUE and p not in atoms:
            atoms.append(p)

    for goal in goals:
        add(goal)
    return atoms


def achievers(system: StepSystem, atom: Predicate, path: str) -> list[Achiever]:
    """Steps that can make a one-variable atom true, each with the condition (before it) under which they do.

    A step that can fire only where the atom already holds (tightening a mounted filter keeps it
    `!= absent`) never makes it true and is left out.
    """
    compiled = system.compiled
    values = compiled.domains[compiled.index[path]].values
    found: list[Achiever] = []
    for t in system.transitions:
        guard = compiled.guard_of(t.source)
        own = [item for item in (guard.items if isinstance(guard, And) else (guard,)) if item.paths() == {path}]
        if own and all(atom.eval({path: u}) for u in values if all(item.eval({path: u}) for item in own)):
            continue
        for outcome, actions in enumerate(t.source.outcomes):
            for action in actions:
                if action.path != path:
                    continue
                if isinstance(action.value, Ref):
                    found.append((t, outcome, rename(atom, path, action.value.path)))
                elif atom.eval({path: action.value}):
                    found.append((t, outcome, TRUE))
    return found


class ConjunctionGroup:
    """A pattern database: the abstract distance to the conjunction of atoms inside the projection."""

    def __init__(self, abstraction: Abstraction, atoms: Sequence[Predicate]) -> None:
        self.abstraction = abstraction
        self.atoms = tuple(atoms)
        self.goal = atoms[0] if len(atoms) == 1 else And(tuple(atoms))
        self._goal_states: list[int] | None = None
        self.table: list[int] = []
        self.index = abstraction.index
        self._version = -1

    def prepare(self, start: State, stop: StopTest | None = None) -> None:
        abstraction = self.abstraction
        abstraction.reach_from_initial(stop)
        abstraction.reach_from(self.index(start), stop)
        if self._version != abstraction.reachable_version:
            if self._goal_states is None:
                self._goal_states = abstraction.states_where(self.goal)
            goal_states = self._goal_states
            self.table = abstraction.distances(("holds", self.goal), lambda: ((x, 0) for x in goal_states), stop)
            self._version = abstraction.reachable_version

    def ready_for(self, start: State) -> bool:
        """`prepare(start)` would build nothing."""
        return self.abstraction.covers(self.index(start)) and self._version == self.abstraction.reachable_version

    def value(self, s: State) -> int:
        return self.table[self.index(s)]

    def __str__(self) -> str:
        return f"{' && '.join(map(str, self.atoms))} over [{self.abstraction.describe()}]"


Group = ConjunctionGroup | TourGroup


@dataclass
class HeuristicOptions:
    cap: int = DEFAULT_CAP
    tours: bool = True  # share projections between one-variable atoms (else one database per atom)
    arborescence: bool = True  # the class arborescence on top of the cheapest incoming edges
    patterns: int = 4  # per family of atoms: its cone, then resource patterns for what the cone left out
    potential: int = 1  # tour bounds: steps of work ahead a firing state may carry (0: no potentials)
    landmarks: bool = True  # tour atoms whose achievers need their own variable set first (a bolt placed)


class GoalHeuristic:
    """h(s) for one goal conjunction; built once, then cheap per state.

    Atoms come in families (tour atoms whose achievers read the same variables; inside
    atoms merged while their cones fit under the cap). Each family gets a few patterns:
    first its cone, nearest variables first, up to the cap; then, for every resource with
    cone variables left out, a pattern of that resource's variables with the family's seed.
    Costs are partitioned zero-one (`_partition`): a transition costs 1 in one pattern
    and 0 in the others, so all the patterns' values add up.
    """

    def __init__(
        self,
        system: StepSystem,
        goals: Sequence[Predicate],
        abstraction: Callable[[tuple[int, ...], frozenset[int]], Abstraction],
        options: HeuristicOptions | None = None,
        stop: StopTest | None = None,
    ) -> None:
        """`stop` ends the build (`stopping.Stopped`): the owner stores the heuristic only once it is built."""
        began = time.perf_counter()
        self.options = options or HeuristicOptions()
        compiled = system.compiled
        self.system = system
        self.atoms = goal_atoms(goals)
        self.impossible = any(a == FALSE for a in self.atoms)
        self.atoms = [a for a in self.atoms if not isinstance(a, Const)]
        self.groups: list[Group] = []
        index = compiled.index
        writers: dict[int, list[CompiledTransition]] = {}
        for t in system.transitions:
            for i in t.writes:
                writers.setdefault(i, []).append(t)
        self._writers = writers
        # Tour atoms: one variable, read by nothing but its own achievers.
        tour: list[tuple[Predicate, list[Achiever]]] = []
        inside: list[Predicate] = []
        for atom in self.atoms:
            check_stop(stop)
            paths = atom.paths()
            if self.options.tours and len(paths) == 1:
                (path,) = paths
                found = achievers(system, atom, path)
                achieving = {t.number for t, _, _ in found}
                readers = {t.number for t in system.transitions if index[path] in t.reads}
                if readers <= achieving:
                    tour.append((atom, found))
                    continue
            inside.append(atom)
        excluded = {index[next(iter(a.paths()))] for a, _ in tour}
        families: dict[tuple[int, ...], list[tuple[Predicate, list[Achiever]]]] = {}
        for atom, found in tour:
            reads = {index[p] for t, _, c in found for p in compiled.guard_of(t.source).paths() | c.paths()}
            families.setdefault(tuple(sorted(reads - excluded)), []).append((atom, found))
        # Two ways to cover what a family's cone leaves out (see `_patterns`), each with and without the
        # enabling landmarks; `prepare` keeps the collection with the largest value at the start.
        landmarks = self._landmarks(tour) if self.options.landmarks else []
        self._candidates: list[list[Group]] = []
        wholes = (False, True) if self.options.patterns > 1 else (False,)
        family_depths = {seed: self._depths((), seed, excluded) for seed in families}
        for enabling in (True, False) if landmarks else (False,):
            merged = self._merge([*inside, *landmarks] if enabling else inside, excluded, stop)
            merged_depths = [self._depths(required, (), excluded) for required, _ in merged]
            for whole in wholes:
                plans: list[tuple[tuple[int, ...], list[tuple[Predicate, list[Achiever]]] | list[Predicate],
                                  bool]] = []
                depths: list[dict[int, int]] = []
                for seed, members in families.items():
                    check_stop(stop)
                    for v in self._patterns((), seed, excluded, whole):
                        plans.append((v, members, True))
                        depths.append(family_depths[seed])
                for (required, atoms), depth in zip(merged, merged_depths, strict=True):
                    check_stop(stop)
                    for v in self._patterns(required, (), excluded, whole):
                        plans.append((v, atoms, False))
                        depths.append(depth)
                self._candidates.append(self._groups(plans, depths, abstraction, stop))
        self.groups = self._candidates[0]
        self._unsatisfied = generate(
            " + ".join(f"(not {predicate_source(a, index)})" for a in self.atoms) + " + 0" if self.atoms else "0"
        )
        self.per_step = max(
            (sum(1 for a in self.atoms if a.paths() & {compiled.paths[i] for i in t.writes})
             for t in system.transitions),
            default=0,
        )
        self.build_seconds = time.perf_counter() - began

    # --- construction --------------------------------------------------------------------
    def _groups(
        self,
        plans: Sequence[tuple[tuple[int, ...], list[tuple[Predicate, list[Achiever]]] | list[Predicate], bool]],
        depths: Sequence[dict[int, int]],
        abstraction: Callable[[tuple[int, ...], frozenset[int]], Abstraction],
        stop: StopTest | None,
    ) -> list[Group]:
        groups: list[Group] = []
        index = self.system.compiled.index
        for (variables, members, is_tour), costs in zip(plans, self._partition(plans, depths), strict=True):
            check_stop(stop)
            if not costs:
                continue
            writing = frozenset(self._written_by(variables))
            if is_tour:
                groups.append(TourGroup(abstraction(variables, costs & writing), [a for a, _ in members],  # type: ignore[misc]  # a tour's members are (atom, achievers) pairs (is_tour)
                                        [f for _, f in members], index, costs, self.options.arborescence,  # type: ignore[misc]  # a tour's members are (atom, achievers) pairs (is_tour)
                                        self.options.potential, stop))
            else:
                groups.append(ConjunctionGroup(abstraction(variables, costs & writing), members))  # type: ignore[arg-type]  # a pattern's members are atoms (not is_tour)
        return groups

    def _partition(
        self,
        plans: Sequence[tuple[tuple[int, ...], list[tuple[Predicate, list[Achiever]]] | list[Predicate], bool]],
        depths: Sequence[dict[int, int]],
    ) -> list[frozenset[int]]:
        """Zero-one cost partitioning: each transition counts (costs 1) in exactly one pattern.

        A transition goes to the pattern that holds most of the variables it writes (a pattern holding
        only part of its effect may never need it: a reset that clears the torque flag together with the
        spindle), then to the one whose goal it is nearest to (the operator's steps count for the filters
        the operator mounts, not for the bolts, whose projections hold the operator only because the
        supervisor reads it), then the one holding most of what it reads, then the earliest. The
        achievers of a tour family count in the family's first pattern (a landmark that holds a tour
        variable never needs the atom achieved).
        """
        chosen: dict[int, int] = {}
        best: dict[int, tuple[int, int, int]] = {}
        achieving = {t.number for _, members, is_tour in plans if is_tour for t, _, _ in _achievers(members)}
        for n, (variables, _, _) in enumerate(plans):
            held = set(variables)
            depth = depths[n]
            for t in self.system.transitions:
                if t.number in achieving:
                    continue
                written = t.writes & held
                if not written:
                    continue
                key = (len(written), -min(depth.get(v, len(depth)) for v in written), len(t.reads & held))
                if key > best.get(t.number, (0, -len(depth) - 1, 0)):
                    best[t.number] = key
                    chosen[t.number] = n
        first_of_family: dict[int, int] = {}
        for n, (_, members, is_tour) in enumerate(plans):
            if is_tour:
                first_of_family.setdefault(id(members), n)
        for n, (_, members, is_tour) in enumerate(plans):
            if is_tour and first_of_family[id(members)] == n:
                for t, _, _ in _achievers(members):
                    chosen.setdefault(t.number, n)
        costs: list[set[int]] = [set() for _ in plans]
        for number, n in chosen.items():
            costs[n].add(number)
        return [frozenset(c) for c in costs]

    def _landmarks(self, tour: Sequence[tuple[Predicate, list[Achiever]]]) -> list[Predicate]:
        """Enabling landmarks of tour atoms: `x in {enabling values, goal value}`, as further inside atoms.

        A bolt is tightened only once placed, and placing is another resource's work (the
        operator's) that the tour projections, leaving `x` out, never need. Every goal state
        satisfies `x in {placed, tightened}`, so counting it with the inside atoms stays a lower
        bound. One landmark per set of enabling writers: placing all 24 bolts is one task.
        """
        compiled = self.system.compiled
        index, domains = compiled.index, compiled.domains
        found: dict[frozenset[int], Predicate] = {}
        for atom, achieved_by in tour:
            (path,) = atom.paths()
            x = index[path]
            values = domains[x].values
            enabling = set(values)
            for t, _, _ in achieved_by:
                guard = compiled.guard_of(t.source)
                for item in guard.items if isinstance(guard, And) else (guard,):
                    if item.paths() == {path}:
                        enabling &= {u for u in values if item.eval({path: u})}
            allowed = tuple(u for u in values if u in enabling or atom.eval({path: u}))
            if len(allowed) == len(values):
                continue
            achieving = {t.number for t, _, _ in achieved_by}
            writers = frozenset(t.number for t in self._writers.get(x, ()) if t.number not in achieving)
            if writers and writers not in found:
                found[writers] = In(path, allowed)
        return list(found.values())

    def _written_by(self, variables: Iterable[int]) -> set[int]:
        return {t.number for v in variables for t in self._writers.get(v, ())}

    def _depths(self, required: Sequence[int], seed: Iterable[int], excluded: set[int]) -> dict[int, int]:
        """How many writer hops each variable of the cone is from the goal's own variables (0: theirs)."""
        layer = [v for v in dict.fromkeys([*required, *sorted(set(seed))]) if v not in excluded or v in required]
        depth = dict.fromkeys(layer, 0)
        hops = 0
        while layer:
            hops += 1
            following = []
            for v in layer:
                for t in self._writers.get(v, ()):
                    for r in t.reads:
                        if r not in depth and r not in excluded:
                            depth[r] = hops
                            following.append(r)
            layer = following
        return depth

    def _influence(self, required: Sequence[int], seed: Iterable[int], excluded: set[int]) -> list[int]:
        """The variables that can influence the required and seed ones, nearest first (no cap).

        Variables nothing writes are left out (constants: dropping them only loosens guards), as are
        `excluded` ones (the tour atoms' own variables).
        """
        order = list(dict.fromkeys(required))
        seen = set(order) | set(excluded)
        for v in sorted(set(seed) - seen):
            seen.add(v)
            if v in self._writers:
                order.append(v)
        k = 0
        while k < len(order):
            for t in self._writers.get(order[k], ()):
                for r in sorted(t.reads):
                    if r not in seen:
                        seen.add(r)
                        if r in self._writers:
                            order.append(r)
            k += 1
        return order

    def _fill(self, first: Sequence[int], then: Sequence[int]) -> tuple[int, ...]:
        """`first` (all of it), then variables of `then` in order while the product of domains fits the cap."""
        domains = self.system.compiled.domains
        chosen = list(dict.fromkeys(first))
        product = 1
        for v in chosen:
            product *= len(domains[v].values)
        for v in then:
            if v in chosen:
                continue
            size = len(domains[v].values)
            if product * size <= self.options.cap:
                chosen.append(v)
                product *= size
        return tuple(sorted(chosen))

    def _patterns(
        self, required: Sequence[int], seed: Iterable[int], excluded: set[int], whole: bool = False
    ) -> list[tuple[int, ...]]:
        """The family's cone under the cap, then one pattern per resource whose cone variables it missed.

        A resource pattern starts with the variables the cone missed (`whole`: all the resource's
        variables, so that its transitions are modelled whole), then the seed, then the rest of the cone.
        Neither choice is best everywhere: a tool's lift and a nutrunner's cycle want different ones.
        """
        order = self._influence(required, seed, excluded)
        patterns = [self._fill(required, order)]
        if self.options.patterns <= 1:
            return patterns
        covered = set(patterns[0])
        paths = self.system.compiled.paths
        seeds = [v for v in order if v in set(seed)]
        # Resources by their nearest variable the cone left out (a resource read by the goal's own writers
        # before one only reachable through several hops).
        left_out = [v for v in order if v not in covered]
        for resource in dict.fromkeys(paths[v].split(".", 1)[0] for v in left_out):
            own = [v for v in order if v not in covered and paths[v].startswith(resource + ".")]
            if not own:
                continue
            if whole:
                own = [v for v in order if paths[v].startswith(resource + ".")]
            pattern = self._fill(required, [*own, *seeds, *order])
            if set(pattern) <= covered:
                continue
            covered |= set(pattern)
            patterns.append(pattern)
            if len(patterns) >= self.options.patterns:
                break
        return patterns

    def _merge(self, atoms: list[Predicate], excluded: set[int],
               stop: StopTest | None) -> list[tuple[tuple[int, ...], list[Predicate]]]:
        """Inside atoms merged greedily while their cones fit under the cap: (their variables, atoms)."""
        domains = self.system.compiled.domains
        index = self.system.compiled.index

        def states(variables: Iterable[int]) -> int:
            product = 1
            for v in variables:
                product *= len(domains[v].values)
            return product

        merged: list[tuple[set[int], set[int], list[Predicate]]] = []  # (own variables, cone, atoms)
        for atom in atoms:
            check_stop(stop)
            own = sorted(index[p] for p in atom.paths())
            # Merged on their cores (the atom's variables and what their writers read): the operator's
            # three filters share one small pattern instead of each filling its own up to the cap.
            paths = atom.paths()
            if len(paths) == 1:  # what its achievers read (steps that need it already true do not count)
                core = sorted({v for t, _, _ in achievers(self.system, atom, next(iter(paths))) for v in t.reads}
                              - excluded)
            else:
                depth = self._depths(own, (), excluded)
                core = sorted((v for v, d in depth.items() if d <= 1), key=depth.__getitem__)
            cone = set(self._fill(own, core))
            best = None
            for group in merged:
                union = group[1] | cone
                if (states(union) <= self.options.cap and group[1] & cone
                        and (best is None or len(group[1] & cone) > len(best[1] & cone))):
                    best = group
            if best is None:
                merged.append((set(own), cone, [atom]))
            else:
                best[0].update(own)
                best[1].update(cone)
                best[2].append(atom)
        return [(tuple(sorted(own)), members) for own, _, members in merged]

    # --- evaluation --------------------------------------------------------------------------
    def prepare(self, start: State, stop: StopTest | None = None) -> None:
        """Call before evaluating states reachable from `start`: the tables cover the reachable states only.

        The first call also picks, of the candidate pattern collections, the one with the larger value at
        `start` (both are admissible); the other is dropped. `stop` ends the preparation
        (`stopping.Stopped`); each group stores its tables whole, so a later call goes on from there.
        """
        if len(self._candidates) > 1:
            best = -1
            for groups in self._candidates:
                for g in groups:
                    g.prepare(start, stop)
                value = self._value(groups, start)
                if value > best:
                    best, chosen = value, groups
            self.groups = chosen
            self._candidates = [chosen]
        for g in self.groups:
            g.prepare(start, stop)

    def ready_for(self, start: State) -> bool:
        """`prepare(start)` would build nothing: a search from `start` costs no table build."""
        return len(self._candidates) == 1 and all(g.ready_for(start) for g in self.groups)

    def __call__(self, s: State) -> int:
        return self._value(self.groups, s)

    def _value(self, groups: Sequence[Group], s: State) -> int:
        if self.impossible:
            return INF
        unsatisfied: int = self._unsatisfied(s)  # type: ignore[assignment]  # a generated function (exec) returns an int
        if not unsatisfied:
            return 0
        if self.per_step == 0:
            return INF
        best = -(-unsatisfied // self.per_step)
        total = 0
        for g in groups:
            total += g.value(s)
        if total > best:
            best = total
        return best if best < INF else INF

    def why_unreachable(self, s: State) -> str:
        """Which part of the heuristic proves the goal unreachable from `s`."""
        if self.impossible:
            return "a goal is the constant false"
        if self.per_step == 0:
            return "no transition writes the goal variables"
        for g in self.groups:
            if g.value(s) >= INF:
                return f"unreachable in the projection: {g}"
        return "unreachable"

    def describe(self) -> str:
        return "; ".join(str(g) for g in self.groups) or "(no groups)"


def _achievers(members: list[tuple[Predicate, list[Achiever]]] | list[Predicate]) -> Iterator[Achiever]:
    """The achievers of a tour family's atoms (a tour's members are (atom, achievers) pairs, a pattern's atoms)."""
    for member in members:
        if isinstance(member, tuple):
            yield from member[1]
