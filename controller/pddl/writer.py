"""A task written as PDDL text: a domain (facts, derived predicates, actions) and a problem (start, goal).

Two flavours of the same task:

* `Flavour.AXIOMS` (the default): every disjunction and every named condition (`stable`,
  `allowed`, `idle-…`, `no-race-…`) is a derived predicate, so each action's precondition is a
  conjunction of atoms. Fast Downward's translator turns disjunctive preconditions into one
  operator per disjunct of their disjunctive normal form, which explodes on a station (the
  urgency condition alone is a conjunction of one disjunction per automatic transition);
  through derived predicates the task stays the size of the model.
* `Flavour.INLINE`: the same conditions written out in place, plain ADL without derived
  predicates, for tools that read no `:derived` (unified-planning's reader, and so the
  validator) and planners without axiom support; fine for small models.
"""

from __future__ import annotations

from enum import Enum

from .encoding import Action, Condition, Effect, Task
from .formulas import NEVER, AllOf, AnyOf, Fact, Named, Other

NEVER_FACT = "never"  # a fact no state has: what an empty disjunction is


class Flavour(Enum):
    AXIOMS = "axioms"
    INLINE = "inline"
    FLAT = "flat"  # no derived predicates, disjunctions or conditional effects: `flat.py` writes it
    SAS = "sas"  # Fast Downward's own input, the model's variables multi-valued: `sas.py` writes it


class Writer:
    def __init__(self, task: Task, flavour: Flavour) -> None:
        self.task = task
        self.flavour = flavour
        self.derived: dict[Condition, str] = {}
        self.rules: list[str] = []

    # --- conditions ------------------------------------------------------------------------
    def atoms(self, condition: Condition) -> list[str]:
        """The condition as a conjunction of atoms (AXIOMS) or of formulas (INLINE)."""
        if isinstance(condition, Fact):
            return [f"({self.task.facts[condition]})"]
        if condition == NEVER:
            return [f"({NEVER_FACT})"]
        if isinstance(condition, AllOf):
            return [a for item in condition.items for a in self.atoms(item)]
        if self.flavour is Flavour.INLINE:
            return [self.inline(condition)]
        return [self.derive(condition)]

    def inline(self, condition: Condition) -> str:
        if isinstance(condition, Named):
            return self.inline(condition.formula)
        if isinstance(condition, Fact):
            return f"({self.task.facts[condition]})"
        if condition == NEVER:
            return f"({NEVER_FACT})"
        if isinstance(condition, Other):
            return f"(not ({self.task.facts[condition.fact]}))"
        connective = "and" if isinstance(condition, AllOf) else "or"
        return f"({connective} {' '.join(self.inline(i) for i in condition.items)})"

    def others(self, condition: Other) -> list[Fact]:
        return [f for f in self.task.facts if f.path == condition.fact.path and f != condition.fact]

    def derive(self, condition: Named | AnyOf | Other) -> str:
        name = self.derived.get(condition)
        if name is None:
            if isinstance(condition, Other):
                name = self.task.names.make(f"not-{self.task.facts[condition.fact]}")
                body = "(or " + " ".join(f"({self.task.facts[f]})" for f in self.others(condition)) + ")"
            elif isinstance(condition, Named):
                name = condition.name
                body = conjunction(self.atoms(condition.formula))
            else:
                name = self.task.names.make("any")
                body = "(or " + " ".join(conjunction(self.atoms(item)) for item in condition.items) + ")"
            self.derived[condition] = name
            self.rules.append(f"  (:derived ({name})\n    {body})")
        return f"({name})"

    # --- text ---------------------------------------------------------------------------------
    def action(self, action: Action) -> str:
        pre = conjunction([a for c in action.precondition for a in self.atoms(c)])
        effects = " ".join(effect_text(self.task, e) for e in action.effects)
        return (f"  (:action {action.name}\n    :parameters ()\n    :precondition {pre}\n"
                f"    :effect (and {effects}))")

    def domain(self) -> tuple[str, str]:
        """(domain text, goal condition text): the goal's derived predicates live in the domain."""
        actions = [self.action(a) for a in self.task.actions]
        goal = conjunction([a for c in self.task.goal for a in self.atoms(c)])
        requirements = ":strips :disjunctive-preconditions :conditional-effects"
        requirements += " :derived-predicates" if self.flavour is Flavour.AXIOMS else " :negative-preconditions"
        predicates = [f"({n})" for n in self.task.facts.values()]
        predicates += [f"({NEVER_FACT})"] + [f"({n})" for n in self.derived.values()]
        lines = [f"(define (domain {self.task.name})", f"  (:requirements {requirements})",
                 "  (:predicates " + "\n    ".join(predicates) + ")"]
        return "\n".join(lines + self.rules + actions) + ")\n", goal

    def problem(self, goal: str) -> str:
        init = "\n    ".join(f"({self.task.facts[f]})" for f in self.task.init)
        return (f"(define (problem {self.task.name}-problem)\n  (:domain {self.task.name})\n"
                f"  (:init\n    {init})\n  (:goal {goal}))\n")


def conjunction(atoms: list[str]) -> str:
    unique = list(dict.fromkeys(atoms))
    if len(unique) == 1:
        return unique[0]
    return "(and " + " ".join(unique) + ")"


def effect_text(task: Task, effect: Effect) -> str:
    parts = [f"({task.facts[f]})" for f in effect.adds] + [f"(not ({task.facts[f]}))" for f in effect.deletes]
    if not effect.when:
        return " ".join(parts)  # inside the action's (and ...)
    body = parts[0] if len(parts) == 1 else "(and " + " ".join(parts) + ")"
    return f"(when {conjunction([f'({task.facts[f]})' for f in effect.when])} {body})"


def render(task: Task, flavour: Flavour = Flavour.AXIOMS) -> tuple[str, str]:
    """(domain.pddl text, problem.pddl text)."""
    if flavour is Flavour.FLAT:
        from .flat import flatten, render_flat  # flat.py builds on the encoding, as this module does

        return render_flat(flatten(task))
    writer = Writer(task, flavour)
    domain, goal = writer.domain()
    return domain, writer.problem(goal)



