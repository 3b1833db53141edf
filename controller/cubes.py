"""Predicates as unions of cubes: a cube maps some variables to the set of values they may take.

Cubes make the fixpoints of supervisor synthesis cheap: conjunction is set
intersection, implication between cubes is set inclusion, and the weakest
precondition of an assignment moves or discharges one variable's constraint.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from common.model import Domain, Predicate, Value, all_of, any_of
from common.model.actions import Assign
from common.model.predicates import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Or, Ref

Cube = dict[str, frozenset[Value]]  # a variable not in the cube may take any value
Domains = Mapping[str, Domain]


class CubeExplosion(RuntimeError):
    pass


MAX_CUBES = 50_000


def _literal(path: str, allowed: Iterable[Value], domains: Domains) -> list[Cube]:
    values = frozenset(allowed) & frozenset(domains[path].values)
    if not values:
        return []
    if values == frozenset(domains[path].values):
        return [{}]
    return [{path: values}]


def _pair(left: str, right: str, equal: bool, domains: Domains) -> list[Cube]:
    cubes: list[Cube] = []
    common = [v for v in domains[left].values if v in domains[right]]
    if equal:
        return [{left: frozenset([v]), right: frozenset([v])} for v in common]
    for v in domains[left].values:
        others = frozenset(w for w in domains[right].values if w != v)
        if others:
            cubes.append({left: frozenset([v]), right: others} if others != frozenset(domains[right].values)
                         else {left: frozenset([v])})
    return cubes


def conjoin(a: Cube, b: Cube) -> Cube | None:
    result = dict(a)
    for path, values in b.items():
        if path in result:
            values = result[path] & values
            if not values:
                return None
        result[path] = values
    return result


def implies(a: Cube, b: Cube) -> bool:
    """Every state in cube a is in cube b."""
    return all(path in a and a[path] <= values for path, values in b.items())


def to_cubes(p: Predicate, domains: Domains, negate: bool = False) -> list[Cube]:
    """Disjunctive normal form of p (or of !p) as cubes."""
    if isinstance(p, Const):
        return [{}] if p.value != negate else []
    if isinstance(p, Not):
        return to_cubes(p.operand, domains, not negate)
    if isinstance(p, IsTrue):
        return _literal(p.path, [not negate], domains)
    if isinstance(p, Eq | Ne):
        equal = isinstance(p, Eq) != negate
        if isinstance(p.value, Ref):
            return _pair(p.path, p.value.path, equal, domains)
        allowed = [p.value] if equal else [v for v in domains[p.path].values if v != p.value]
        return _literal(p.path, allowed, domains)
    if isinstance(p, In):
        chosen = set(p.values)
        allowed = [v for v in domains[p.path].values if (v in chosen) != negate]
        return _literal(p.path, allowed, domains)
    if isinstance(p, And | Or):
        conjunctive = isinstance(p, And) != negate
        if not conjunctive:
            return prune([c for item in p.items for c in to_cubes(item, domains, negate)])
        cubes: list[Cube] = [{}]
        for item in p.items:
            parts = to_cubes(item, domains, negate)
            cubes = prune([c for a in cubes for b in parts if (c := conjoin(a, b)) is not None])
            if len(cubes) > MAX_CUBES:
                raise CubeExplosion(f"more than {MAX_CUBES} cubes for {p}")
            if not cubes:
                return []
        return cubes
    raise TypeError(f"unknown predicate node {p!r}")


def prune(cubes: list[Cube]) -> list[Cube]:
    """Drop cubes implied by another one."""
    kept: list[Cube] = []
    for cube in sorted(cubes, key=len):  # fewer constraints first: the larger cubes
        if not any(implies(cube, k) for k in kept):
            kept.append(cube)
    return kept


def merge(cubes: list[Cube], domains: Domains) -> list[Cube]:
    """Exactly merge cubes that differ in one variable only (union of its values); then prune."""
    current = prune(cubes)
    changed = True
    while changed and len(current) > 1:
        changed = False
        for path in sorted({p for c in current for p in c}):
            groups: dict[frozenset, list[Cube]] = {}
            rest: list[Cube] = []
            for cube in current:
                if path in cube:
                    key = frozenset((p, v) for p, v in cube.items() if p != path)
                    groups.setdefault(key, []).append(cube)
                else:
                    rest.append(cube)
            if all(len(g) == 1 for g in groups.values()):
                continue
            merged = list(rest)
            full = frozenset(domains[path].values)
            for group in groups.values():
                union = frozenset().union(*(c[path] for c in group))
                cube = dict(group[0])
                if union == full:
                    del cube[path]
                else:
                    cube[path] = union
                merged.append(cube)
                changed = changed or len(group) > 1
            current = prune(merged)
    return current


def before(cube: Cube, actions: tuple[Assign, ...], domains: Domains) -> list[Cube]:
    """The cube of states from which the simultaneous actions lead into `cube` (empty: none)."""
    assigned = {a.path: a.value for a in actions}
    result: Cube = {p: v for p, v in cube.items() if p not in assigned}
    for path, value in assigned.items():
        if path not in cube:
            continue
        if isinstance(value, Ref):
            merged = conjoin(result, {value.path: cube[path]})
            if merged is None:
                return []
            result = merged
        elif value not in cube[path]:
            return []
    return [result]


def to_predicate(cubes: list[Cube], domains: Domains) -> Predicate:
    if not cubes:
        return FALSE
    terms = []
    for cube in cubes:
        literals: list[Predicate] = []
        for path in sorted(cube):
            values = [v for v in domains[path].values if v in cube[path]]
            others = [v for v in domains[path].values if v not in cube[path]]
            if domains[path].is_bool:
                literals.append(IsTrue(path) if values == [True] else Not(IsTrue(path)))
            elif len(values) == 1:
                literals.append(Eq(path, values[0]))
            elif len(others) == 1:
                literals.append(Ne(path, others[0]))
            else:
                literals.append(In(path, tuple(values)))
        terms.append(all_of(*literals) if literals else TRUE)
    return any_of(*terms)


def holds(cubes: list[Cube], state: Mapping[str, Value]) -> bool:
    return any(all(state[p] in values for p, values in cube.items()) for cube in cubes)


__all__ = ["And", "Cube", "CubeExplosion", "Or", "before", "conjoin", "holds", "implies", "merge", "prune",
           "to_cubes", "to_predicate"]
