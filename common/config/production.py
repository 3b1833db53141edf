"""Where a run's orders come from: `[production]` in hubs.toml, or `hubctl up --orders N --mix ...`.

Both become a `ProductionPlan`: the orders to queue when the station starts, in order.

    [production]                 # a list of orders ...
    [[production.orders]]
    variant = "full"
    product_id = "E-1001"        # optional: generated from the order's id
    parameters = { "engine.count_bolts_e" = 22 }   # optional: the variant's parameters, overridden
    count = 1                    # optional: this many such orders (no product_id then)

    [production]                 # ... or a repeating mix: full, full, full, light, full, ...
    mix = { full = 3, light = 1 }
    count = 8

`--orders N` takes its variants from `--mix VARIANT:WEIGHT,...`, else from [production] mix, else
the model's first variant. Variant names and parameters are checked against the station model.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Annotated

import msgspec

from common.model import Model

ParameterValue = bool | int | str
MAX_ORDERS = 100_000  # a plan longer than this is a typo, not a shift


class OrderEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One `[[production.orders]]` table."""

    variant: str
    product_id: str = ""
    parameters: dict[str, ParameterValue] = msgspec.field(default_factory=dict)
    count: Annotated[int, msgspec.Meta(ge=1, le=MAX_ORDERS)] = 1


class ProductionConfig(msgspec.Struct, frozen=True):
    """[production]: `orders`, or `mix` with `count`; empty: no orders (the station runs as it always did)."""

    orders: list[OrderEntry] = msgspec.field(default_factory=list)
    mix: dict[str, Annotated[int, msgspec.Meta(ge=1)]] = msgspec.field(default_factory=dict)
    count: Annotated[int, msgspec.Meta(ge=1, le=MAX_ORDERS)] | None = None

    @property
    def empty(self) -> bool:
        return not self.orders and not self.mix


@dataclass(frozen=True)
class PlannedOrder:
    variant: str
    product_id: str = ""
    parameters: Mapping[str, ParameterValue] | None = None


@dataclass(frozen=True)
class ProductionPlan:
    """The orders a run queues at its start, in order, and where they were given (for messages)."""

    orders: tuple[PlannedOrder, ...]
    source: str

    def counts(self) -> dict[str, int]:
        """Orders per variant, in the order the variants first appear."""
        result: dict[str, int] = {}
        for order in self.orders:
            result[order.variant] = result.get(order.variant, 0) + 1
        return result

    def describe(self) -> str:
        per_variant = ", ".join(f"{n} {variant}" for variant, n in self.counts().items())
        return f"{len(self.orders)} orders ({per_variant}) from {self.source}"


class ProductionError(ValueError):
    """A plan that the options or the station model refuse; the message says which part and why."""


# --- the two sources --------------------------------------------------------------------------

def mixed(mix: Mapping[str, int], count: int) -> tuple[PlannedOrder, ...]:
    """`count` orders repeating the mix's pattern: each variant its weight times, in the mix's order."""
    pattern = [variant for variant, weight in mix.items() for _ in range(weight)]
    return tuple(PlannedOrder(pattern[i % len(pattern)]) for i in range(count))


def plan_from_config(production: ProductionConfig, source: str) -> ProductionPlan | None:
    if production.empty:
        return None
    if production.mix:
        return ProductionPlan(mixed(production.mix, production.count or 0), source)
    orders = tuple(PlannedOrder(entry.variant, entry.product_id, dict(entry.parameters) or None)
                   for entry in production.orders for _ in range(entry.count))
    return ProductionPlan(orders, source)


_MIX_ITEM = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?::\s*(\d+)\s*)?$")


def parse_mix(text: str) -> dict[str, int]:
    """`--mix full:3,light:1` (a weight defaults to 1)."""
    mix: dict[str, int] = {}
    for item in text.split(","):
        match = _MIX_ITEM.match(item)
        if match is None:
            raise ProductionError(f"--mix {text!r}: {item.strip()!r} is not VARIANT or VARIANT:WEIGHT")
        variant, weight = match.group(1), int(match.group(2) or 1)
        if weight < 1:
            raise ProductionError(f"--mix {text!r}: the weight of {variant} must be at least 1")
        if variant in mix:
            raise ProductionError(f"--mix {text!r}: {variant} is given twice")
        mix[variant] = weight
    return mix


def plan_from_options(orders: int | None, mix: str | None, production: ProductionConfig, model: Model,
                      config_path: str) -> ProductionPlan | None:
    """The plan of `hubctl up`: `--orders N [--mix ...]` wins over [production] of hubs.toml; None: no
    orders at all (the station runs its operations once, as it always did). Checked against `model`."""
    if mix is not None and orders is None:
        raise ProductionError("--mix needs --orders N (how many orders to draw from the mix)")
    if orders is not None:
        if not 1 <= orders <= MAX_ORDERS:
            raise ProductionError(f"--orders {orders}: give 1 to {MAX_ORDERS}")
        if mix is not None:
            weights, source = parse_mix(mix), f"--orders {orders} --mix {mix}"
        elif production.mix:
            weights, source = dict(production.mix), f"--orders {orders} with the mix of {config_path} [production]"
        else:
            first = next(iter(model.variant_by_name))
            weights, source = {first: 1}, f"--orders {orders} of variant {first}"
        plan: ProductionPlan | None = ProductionPlan(mixed(weights, orders), source)
    else:
        plan = plan_from_config(production, f"{config_path} [production]")
    if plan is not None:
        problems = plan_problems(plan.orders, model)
        if problems:
            raise ProductionError(f"{plan.source}: {problems[0][1]}")
    return plan


# --- checks -------------------------------------------------------------------------------------

def config_problems(production: ProductionConfig) -> list[tuple[tuple[str, ...], str]]:
    """(key path, message) for what [production] gets wrong on its own, without the model."""
    problems: list[tuple[tuple[str, ...], str]] = []
    if production.orders and production.mix:
        problems.append((("production", "mix"), "give either orders or a mix, not both"))
    if production.mix and production.count is None:
        problems.append((("production", "count"), "a mix needs count: how many orders to draw from it"))
    if production.count is not None and not production.mix:
        problems.append((("production", "count"), "count belongs to a mix (an order table has its own count)"))
    for i, entry in enumerate(production.orders):
        if entry.product_id and entry.count != 1:
            problems.append((("production", f"orders[{i}]", "product_id"),
                             "a product id names one order: remove it or count"))
    return problems


def plan_problems(orders: Iterable[PlannedOrder], model: Model) -> list[tuple[int, str]]:
    """(index of the order, message) for each order the model refuses: an unknown variant or parameter."""
    problems = []
    known = ", ".join(model.variant_by_name)
    for i, order in enumerate(orders):
        chosen = model.variant_by_name.get(order.variant)
        if chosen is None:
            problems.append((i, f"model {model.name} has no variant {order.variant!r} (its variants: {known})"))
            continue
        for path, value in (order.parameters or {}).items():
            if path not in chosen.parameters:
                problems.append((i, f"variant {order.variant} has no parameter {path} "
                                    f"(its parameters: {', '.join(chosen.parameters) or 'none'})"))
            elif value not in model.variables[path].domain:
                problems.append((i, f"parameter {path} = {value!r} is outside "
                                    f"{model.variables[path].domain.describe()}"))
    return problems


def model_problems(production: ProductionConfig, model: Model) -> list[tuple[tuple[str, ...], str]]:
    """(key path, message) for what [production] asks of a model that it does not have."""
    problems: list[tuple[tuple[str, ...], str]] = []
    known = ", ".join(model.variant_by_name)
    for variant in production.mix:
        if variant not in model.variant_by_name:
            problems.append((("production", "mix", variant),
                             f"model {model.name} has no variant {variant!r} (its variants: {known})"))
    entries = [PlannedOrder(e.variant, e.product_id, e.parameters) for e in production.orders]
    for i, message in plan_problems(entries, model):
        problems.append((("production", f"orders[{i}]"), message))
    return problems


def order_table_lines(text: str) -> list[int]:
    """The line of each `[[production.orders]]` table, in order (KeyLines keeps only a key's first)."""
    header = re.compile(r"^\s*\[\[\s*production\s*\.\s*orders\s*\]\]")
    return [number for number, line in enumerate(text.splitlines(), start=1) if header.match(line)]
