"""Online planners: shortest plans (A* with projection heuristics), a breadth-first baseline, plan checking.

    planner = Planner(compiled, forbidden)
    result = planner.plan(state, {"TightenBolt7": goal}, disabled=frozenset({"agv"}))
    if isinstance(result, Plan): print(result.explain(compiled))
    else: print(result.reason, result.unreachable)
"""

from .bfs import breadth_first
from .check import check_operations
from .heuristics import GoalHeuristic, HeuristicOptions
from .planner import Planner
from .plans import NoPlan, Plan, PlanStats, PlanStep
from .portfolio import Budget
from .validate import PlanInvalid, validate_plan

__all__ = [
    "Budget", "GoalHeuristic", "HeuristicOptions", "NoPlan", "Plan", "PlanInvalid", "PlanStats", "PlanStep", "Planner",
    "breadth_first", "check_operations", "validate_plan",
]
