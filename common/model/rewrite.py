"""Predicate rewriting: substitution of assignments (weakest precondition) and constant folding."""

from __future__ import annotations

from collections.abc import Mapping

from .actions import Assign
from .predicates import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Operand, Or, Predicate, Ref, all_of, any_of
from .variables import Value


def after(predicate: Predicate, actions: tuple[Assign, ...]) -> Predicate:
    """The predicate that holds before the (simultaneous) actions exactly when `predicate` holds after them."""
    assigned: dict[str, Operand] = {a.path: a.value for a in actions}
    return simplify(_substitute(predicate, assigned))


def _value(path: str, assigned: Mapping[str, Operand]) -> Operand | None:
    return assigned.get(path)


def _compare(left: Operand, right: Operand, equal: bool) -> Predicate:
    if isinstance(left, Ref) and isinstance(right, Ref):
        if left.path == right.path:
            return Const(equal)
        return Eq(left.path, right) if equal else Ne(left.path, right)
    if isinstance(left, Ref):
        return Eq(left.path, right) if equal else Ne(left.path, right)
    if isinstance(right, Ref):
        return Eq(right.path, left) if equal else Ne(right.path, left)
    same = left == right and type(left) is type(right)
    return Const(same if equal else not same)


def _substitute(p: Predicate, assigned: Mapping[str, Operand]) -> Predicate:
    if isinstance(p, Const):
        return p
    if isinstance(p, IsTrue):
        new = assigned.get(p.path)
        if new is None:
            return p
        return IsTrue(new.path) if isinstance(new, Ref) else Const(new is True)
    if isinstance(p, Eq | Ne):
        left: Operand = assigned.get(p.path, Ref(p.path))
        right: Operand = p.value
        if isinstance(right, Ref):
            right = assigned.get(right.path, right)
        return _compare(left, right, isinstance(p, Eq))
    if isinstance(p, In):
        new = assigned.get(p.path)
        if new is None:
            return p
        if isinstance(new, Ref):
            return In(new.path, p.values)
        return Const(any(new == v and type(new) is type(v) for v in p.values))
    if isinstance(p, Not):
        return Not(_substitute(p.operand, assigned))
    if isinstance(p, And):
        return And(tuple(_substitute(i, assigned) for i in p.items))
    if isinstance(p, Or):
        return Or(tuple(_substitute(i, assigned) for i in p.items))
    raise TypeError(f"unknown predicate node {p!r}")


def simplify(p: Predicate) -> Predicate:
    """Fold constants, flatten nested and/or, drop duplicates; keeps meaning."""
    if isinstance(p, Not):
        inner = simplify(p.operand)
        if isinstance(inner, Const):
            return Const(not inner.value)
        if isinstance(inner, Not):
            return inner.operand
        return Not(inner)
    if isinstance(p, And | Or):
        is_and = isinstance(p, And)
        items: list[Predicate] = []
        for item in (simplify(i) for i in p.items):
            if isinstance(item, Const):
                if item.value != is_and:
                    return Const(item.value)  # false in an and, true in an or
                continue
            flat = item.items if isinstance(item, type(p)) else (item,)
            for f in flat:
                if f not in items:
                    items.append(f)
        if not items:
            return TRUE if is_and else FALSE
        return all_of(*items) if is_and else any_of(*items)
    if isinstance(p, In) and len(p.values) == 1:
        return Eq(p.path, p.values[0])
    return p


def evaluate(p: Predicate, state: Mapping[str, Value]) -> bool:
    return p.eval(state)
