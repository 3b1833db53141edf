"""A task written in Fast Downward's own input language (SAS+), with the model's finite-domain variables.

PDDL has only true/false facts, so the model's variables reach a planner as one fact per value, and Fast
Downward's translator has to rediscover that exactly one of them holds (its invariant synthesis: 37 s on the
reference station, and it finds no groups in the axioms flavour). A symbolic planner then spends one BDD
variable per fact: 4,135 on the reference station. Written here directly, each model variable is one SAS+
variable with its own domain, as statehub's own symbolic member encodes it, and the translator is not needed.

The task is the same as the PDDL flavours' (`encoding.py`): every named or disjunctive condition becomes a
derived variable (SAS+ axioms, layered by what they read; they occur only positively, so that is a
stratification), each action an operator of cost 1 whose precondition is a conjunction of (variable, value)
conditions, a copy `x := y` one conditional effect per value of `y`. The format is Fast Downward's `output.sas`
(version 3, `doc/sas-format` in its sources); any planner built on Fast Downward reads it, SymK among them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .encoding import Condition, Task
from .formulas import AllOf, AnyOf, Fact, Named, Other

Atom = tuple[int, int]  # (SAS+ variable, value)
TRUE_VALUE, DEFAULT_VALUE = 0, 1  # a derived variable's values, as Fast Downward's translator writes them


@dataclass
class SasTask:
    """The task in SAS+ terms, before it is written out."""

    variables: list[tuple[str, tuple[str, ...], int]] = field(default_factory=list)  # name, value names, layer
    init: list[int] = field(default_factory=list)
    goal: list[Atom] = field(default_factory=list)
    # name, prevail, effects (conditions, variable, value before or -1, value after)
    operators: list[tuple[str, list[Atom], list[tuple[list[Atom], int, int, int]]]] = field(default_factory=list)
    rules: list[tuple[list[Atom], int]] = field(default_factory=list)  # body, derived variable made true

    def text(self) -> str:
        lines = ["begin_version", "3", "end_version", "begin_metric", "1", "end_metric", str(len(self.variables))]
        for name, values, layer in self.variables:
            lines += ["begin_variable", name, str(layer), str(len(values)), *values, "end_variable"]
        lines += ["0", "begin_state", *map(str, self.init), "end_state"]
        lines += ["begin_goal", str(len(self.goal)), *(f"{v} {x}" for v, x in self.goal), "end_goal"]
        lines.append(str(len(self.operators)))
        for name, prevail, effects in self.operators:
            lines += ["begin_operator", name, str(len(prevail)), *(f"{v} {x}" for v, x in prevail), str(len(effects))]
            for when, variable, before, after in effects:
                condition = " ".join(f"{v} {x}" for v, x in when)
                lines.append(f"{len(when)} {condition + ' ' if condition else ''}{variable} {before} {after}")
            lines += ["1", "end_operator"]
        lines.append(str(len(self.rules)))
        for body, head in self.rules:
            lines += ["begin_rule", str(len(body)), *(f"{v} {x}" for v, x in body), f"{head} {DEFAULT_VALUE} "
                      f"{TRUE_VALUE}", "end_rule"]
        return "\n".join(lines) + "\n"


class SasWriter:
    def __init__(self, task: Task) -> None:
        self.task = task
        self.sas = SasTask()
        self.atom: dict[Fact, Atom] = {}
        paths: dict[str, list[Fact]] = {}
        for fact in task.facts:
            paths.setdefault(fact.path, []).append(fact)
        written = {f.path for action in task.actions for effect in action.effects for f in effect.adds}
        # Variables no action writes first, then model order, as statehub's symbolic member orders its BDD
        # variables (controller/planner/symbolic_encoding.py variable_order); a symbolic planner without its own
        # ordering keeps this one.
        order = [p for p in paths if p not in written] + [p for p in paths if p in written]
        for facts in (paths[p] for p in order):
            number = len(self.sas.variables)
            self.sas.variables.append((f"var{number}", tuple(f"Atom {task.facts[f]}()" for f in facts), -1))
            self.atom.update({f: (number, i) for i, f in enumerate(facts)})
        self.paths = paths
        self.derived: dict[Condition, int] = {}
        self.layer: dict[int, int] = {}  # derived variable: its axiom layer

    def conjunction(self, condition: Condition) -> list[Atom] | None:
        """The condition as (variable, value) conditions, derived ones for what is not a fact; None if the
        conjunction is contradictory (a variable with two values), which no state satisfies."""
        atoms: dict[int, int] = {}
        for item in condition.items if isinstance(condition, AllOf) else (condition,):
            variable, value = self.atom[item] if isinstance(item, Fact) else (self.derive(item), TRUE_VALUE)
            if atoms.setdefault(variable, value) != value:
                return None
        return list(atoms.items())

    def derive(self, condition: Condition) -> int:
        known = self.derived.get(condition)
        if known is not None:
            return known
        formula = condition.formula if isinstance(condition, Named) else condition
        if isinstance(formula, Other):
            bodies: list[Condition] = [f for f in self.paths[formula.fact.path] if f != formula.fact]
        elif isinstance(formula, AnyOf):
            bodies = list(formula.items)
        else:
            bodies = [formula]
        rules = [body for body in map(self.conjunction, bodies) if body is not None]
        # Its layer is above every derived variable its rules read: a planner evaluates the layers in turn, with no
        # fixpoint (SymK builds each derived variable's BDD from the layers below; all in one layer, it never ends).
        layer = 1 + max((self.layer[v] for body in rules for v, _ in body if v in self.layer), default=-1)
        number = len(self.sas.variables)
        label = condition.name if isinstance(condition, Named) else f"derived{number}"
        self.sas.variables.append((f"var{number}", (f"Atom {label}()", f"NegatedAtom {label}()"), layer))
        self.derived[condition] = number
        self.layer[number] = layer
        self.sas.rules += [(body, number) for body in rules]
        return number

    def write(self) -> SasTask:
        task, sas = self.task, self.sas
        sas.init = [0] * len(sas.variables)  # the model's variables; no derived one exists yet
        for fact in task.init:
            variable, value = self.atom[fact]
            sas.init[variable] = value
        for action in task.actions:
            precondition = self.conjunction(AllOf(action.precondition))  # AllOf(()) is ALWAYS: no condition
            if precondition is None:
                continue  # never applicable
            required = dict(precondition)
            effects: list[tuple[list[Atom], int, int, int]] = []
            for effect in action.effects:
                when = self.conjunction(AllOf(effect.when))
                if when is None:
                    continue
                for fact in effect.adds:
                    variable, value = self.atom[fact]
                    # As the translator writes it: what an unconditional effect's variable must be before is the
                    # effect's own precondition, not a prevail condition.
                    before = required.pop(variable, -1) if not when else -1
                    effects.append((when, variable, before, value))
            prevail = [(v, x) for v, x in precondition if v in required]
            sas.operators.append((action.name, prevail, effects))
        goal = self.conjunction(AllOf(task.goal))
        # A goal no state satisfies: a derived variable without rules, never true.
        sas.goal = goal if goal is not None else [(self.derive(AnyOf(())), TRUE_VALUE)]
        # Derived variables start at their default (false); the search evaluates the axioms on every state.
        sas.init += [DEFAULT_VALUE] * (len(sas.variables) - len(sas.init))
        return sas


def render_sas(task: Task) -> str:
    """The task as Fast Downward's `output.sas` text."""
    return SasWriter(task).write().text()
