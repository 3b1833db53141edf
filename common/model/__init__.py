"""The modelling language: variables, predicates, transitions, abilities, resources, operations, specs, Model."""

from .abilities import STANDARD_PHASES, Ability, Phase, ability, tracking
from .actions import Assign, apply_all
from .durations import Duration, DurationTable
from .model import Model, ModelError, Problem
from .operations import (
    OPERATION_STATES,
    RUNNING,
    Operation,
    OperationState,
    Specification,
    forbid,
    operation,
    operation_running,
)
from .parser import ParseError, parse_action, parse_predicate
from .predicates import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref, all_of, any_of
from .resource import Resource
from .transitions import ActionsLike, Transition, TransitionKind, automatic, deliberate, effect
from .variables import BOOL, Domain, Kind, Value, Variable, command, estimated, measured
from .variants import DEFAULT_VARIANT, Variant, variant

__all__ = [
    "BOOL",
    "DEFAULT_VARIANT",
    "FALSE",
    "OPERATION_STATES",
    "RUNNING",
    "STANDARD_PHASES",
    "TRUE",
    "Ability",
    "ActionsLike",
    "And",
    "Assign",
    "Const",
    "Domain",
    "Duration",
    "DurationTable",
    "Eq",
    "In",
    "IsTrue",
    "Kind",
    "Model",
    "ModelError",
    "Ne",
    "Not",
    "Operation",
    "OperationState",
    "Or",
    "ParseError",
    "Phase",
    "Predicate",
    "Problem",
    "Ref",
    "Resource",
    "Specification",
    "Transition",
    "TransitionKind",
    "Value",
    "Variable",
    "Variant",
    "ability",
    "all_of",
    "any_of",
    "apply_all",
    "automatic",
    "command",
    "deliberate",
    "effect",
    "estimated",
    "forbid",
    "measured",
    "operation",
    "operation_running",
    "parse_action",
    "parse_predicate",
    "tracking",
    "variant",
]
