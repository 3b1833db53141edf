"""The PDDL export checked by planners statehub did not write (docs/pddl.md).

On random models (`test_planner_properties.Generator`: every transition kind, multi-outcome effects,
copies, forbidden states, disabled resources, unstable starts) and on every station's goal sets of
`tests/bench/bench_planner.py`: Fast Downward's optimal search (A* with h^max, admissible on this
encoding) finds plans exactly as long as the shortest statehub shows, and no plan where statehub shows
none; its satisficing plans, read back as statehub transitions, pass `validate_plan` (the engine's
semantics: urgent automatics in model order, races, forbidden states, stable goal); the task written
without derived predicates parses in the validator (pddl-pyvalidator, on unified-planning's reader),
which also finds Fast Downward's plan valid under PDDL's own semantics. Where no optimal planner finishes on
the whole task (the 24 bolts), SymK's optimum on the task projected onto the variables statehub's plan writes (a
relaxation: `controller/pddl/projection.py`) is a lower bound, and statehub's plan meets it.
"""

from __future__ import annotations

import functools
import random
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from common.model import (
    Domain,
    Model,
    Predicate,
    Resource,
    Transition,
    TransitionKind,
    ability,
    all_of,
    command,
    deliberate,
    measured,
)
from common.model.actions import Assign
from common.model.compiled import CompiledModel, State
from common.model.predicates import Eq, Ref
from controller.pddl import Flavour, Unexpressible, encode, render
from controller.pddl.downward import Answer, Search, run_files, solve
from controller.pddl.flat import COPIES, Flattener, Literal
from controller.pddl.projection import plan_variables, project
from controller.pddl.sas import render_sas
from controller.planner import Budget, NoPlan, Plan, Planner, validate_plan
from controller.planner.plans import PlanStats
from controller.planner.validate import plan_from_moves
from deploy.cli import main as hubctl
from tests.test_planner_properties import Generator

if TYPE_CHECKING:
    from tests.bench.bench_planner import Case

pytest.importorskip("up_fast_downward", reason="Fast Downward comes with statehub's test extras")

FAST_SEEDS = range(8)
SLOW_SEEDS = range(1000, 1200)  # 200 models, none shared with the fast part


def write_inline(task_domain_problem: tuple[str, str], directory: Path, plan: tuple[str, ...]) -> tuple[Path, ...]:
    domain, problem = task_domain_problem
    paths = (directory / "domain.pddl", directory / "problem.pddl", directory / "plan")
    paths[0].write_text(domain)
    paths[1].write_text(problem)
    paths[2].write_text("".join(f"({name})\n" for name in plan))
    return paths


def until_shown_shortest(seconds: float) -> Budget:
    """As `hubctl plan` asks: the portfolio until it shows its plan shortest (the symbolic member may need it)."""
    return Budget(first_expansions=10**7, improve_expansions=10**8, seconds=seconds, improve_seconds=seconds)


def check_agreement(compiled: CompiledModel, start: State, goals: dict[str, Predicate], forbidden: Predicate | None,
                    disabled: frozenset[str], label: str, directory: Path | None = None,
                    seconds: float = 30.0, symbolic_too: bool = True) -> str:
    """Fast Downward and statehub agree on the task; returns what was seen (for the failure messages).
    `symbolic_too`: SymK's optimum as well (a search of its own, 0.2 s even on a model of a few states)."""
    goal = all_of(*goals.values())
    task = encode(compiled, start, goal, forbidden, disabled)
    optimal, satisficing = solve(task, (Search.OPTIMAL, Search.SATISFICING), timeout=600)
    (lmcut,) = solve(task, (Search.LMCUT,), timeout=600, flavour=Flavour.FLAT)
    # The same task in SAS+ (multi-valued variables, no translator): h^max, satisficing, SymK's symbolic search.
    on_sas = (Search.OPTIMAL, Search.SATISFICING, *((Search.SYMBOLIC,) if symbolic_too else ()))
    sas = solve(task, on_sas, timeout=600, flavour=Flavour.SAS)
    ours = Planner(compiled, forbidden).plan(start, goals, disabled, budget=until_shown_shortest(seconds))
    if isinstance(ours, NoPlan):
        found = [a.plan for a in (optimal, satisficing, lmcut, *sas) if a.plan is not None]
        assert not found, f"{label}: statehub finds no plan ({ours.reason}), Fast Downward finds {found[0]}"
        return "no plan"
    assert ours.stats.minimal, f"{label}: statehub did not show its plan shortest"
    assert optimal.moves is not None, f"{label}: statehub plans {len(ours.steps)} steps, Fast Downward shows none"
    assert len(optimal.moves) == len(ours.steps), (
        f"{label}: Fast Downward's optimum is {len(optimal.moves)} steps ({', '.join(optimal.plan or ())}), statehub "
        f"shows {len(ours.steps)} shortest:\n{ours.explain(compiled)}")
    assert lmcut.moves is not None and len(lmcut.moves) == len(ours.steps), (
        f"{label}: Fast Downward's optimum on the flat task (lm-cut) is {lmcut.plan}, statehub shows "
        f"{len(ours.steps)} steps shortest")
    optimal_on_sas = {"h^max on SAS+": sas[0], **({"SymK": sas[2]} if symbolic_too else {})}
    for search, answer in optimal_on_sas.items():
        assert answer.moves is not None and len(answer.moves) == len(ours.steps), (
            f"{label}: the optimum of {search} is {answer.plan}, statehub shows {len(ours.steps)} steps shortest")
    for answer in (optimal, satisficing, lmcut, *sas):
        assert answer.moves is not None
        plan = read_back(compiled, start, answer, goals)
        validate_plan(compiled, start, plan, goal, forbidden, disabled)  # raises PlanInvalid, naming the step
    if directory is not None:
        validate_in_pyval(render(task, Flavour.INLINE), directory, satisficing.plan or ())
    return f"{len(ours.steps)} steps"


def check_satisficing(compiled: CompiledModel, start: State, goals: dict[str, Predicate], forbidden: Predicate | None,
                      disabled: frozenset[str], label: str, seconds: float) -> str:
    """Where Fast Downward's optimal search cannot finish (the reference station's long goal sets): its satisficing
    plan, read back, is valid under statehub's semantics, and it is no shorter than the plan statehub shows
    shortest (a shorter valid plan would prove statehub's "shortest" wrong)."""
    goal = all_of(*goals.values())
    task = encode(compiled, start, goal, forbidden, disabled)
    # On SAS+ (no translator): 0.8 s on the 24 bolts, where the PDDL files took minutes to translate and search.
    (satisficing,) = solve(task, (Search.SATISFICING,), timeout=600, flavour=Flavour.SAS)
    ours = Planner(compiled, forbidden).plan(start, goals, disabled, budget=until_shown_shortest(seconds))
    assert isinstance(ours, Plan), f"{label}: statehub finds no plan ({ours.reason})"
    assert ours.stats.minimal, f"{label}: statehub did not show its plan shortest"
    assert satisficing.moves is not None, f"{label}: statehub plans {len(ours.steps)} steps, Fast Downward none"
    validate_plan(compiled, start, read_back(compiled, start, satisficing, goals), goal, forbidden, disabled)
    assert len(satisficing.moves) >= len(ours.steps), (
        f"{label}: Fast Downward's plan of {len(satisficing.moves)} steps is valid and shorter than the "
        f"{len(ours.steps)} statehub shows shortest:\n{', '.join(satisficing.plan or ())}")
    return f"{len(ours.steps)} steps, Fast Downward's satisficing {len(satisficing.moves)}"


def read_back(compiled: CompiledModel, start: State, answer: Answer, goals: dict[str, Predicate]) -> Plan:
    assert answer.moves is not None
    return plan_from_moves(compiled, start, answer.moves, tuple(goals), PlanStats("fast-downward"))


def validate_in_pyval(files: tuple[str, str], directory: Path, plan: tuple[str, ...]) -> None:
    from pyval import PDDLValidator  # type: ignore[import-untyped]  # no type information shipped

    domain, problem, plan_file = write_inline(files, directory, plan)
    result = PDDLValidator().validate(str(domain), str(problem), str(plan_file))
    assert result.is_valid, result.report(verbose=True)


def random_task(seed: int) -> tuple[CompiledModel, State, dict[str, Predicate], Predicate | None, frozenset[str]]:
    compiled, start, goals, forbidden, disabled, _ = Generator(random.Random(seed)).problem()
    return compiled, start, goals, forbidden, disabled


@pytest.mark.parametrize("seed", FAST_SEEDS)
def test_fast_downward_agrees_on_random_models(seed: int, tmp_path: Path) -> None:
    compiled, start, goals, forbidden, disabled = random_task(seed)
    check_agreement(compiled, start, goals, forbidden, disabled, f"random model seed {seed}", tmp_path)


@pytest.mark.slow
def test_fast_downward_agrees_on_200_random_models(tmp_path: Path) -> None:
    seen: dict[str, int] = {}
    for seed in SLOW_SEEDS:
        compiled, start, goals, forbidden, disabled = random_task(seed)
        directory = tmp_path / str(seed)
        directory.mkdir()
        # The validator reads slowly (unified-planning's parser): every tenth model here, every one in the fast part;
        # SymK (0.2 s a model, half the time here) on every fourth, on every one in the fast part and in the
        # projection's 40.
        outcome = check_agreement(compiled, start, goals, forbidden, disabled, f"random model seed {seed}",
                                  directory if seed % 10 == 0 else None, symbolic_too=seed % 4 == 0)
        seen[outcome] = seen.get(outcome, 0) + 1
    assert sum(seen.values()) == len(SLOW_SEEDS)
    # These seeds give 54 models with a plan (0 to 7 steps) and 146 without, where Fast Downward must show
    # none too; fewer plans than that would say the generator changed, and little about lengths.
    assert len(SLOW_SEEDS) - seen.get("no plan", 0) >= 50, f"too few models with a plan: {seen}"


def test_the_optimal_search_is_blind_search_on_random_models() -> None:
    """h^max with derived predicates is admissible only because they occur positively: blind A* agrees."""
    for seed in FAST_SEEDS:
        compiled, start, goals, forbidden, disabled = random_task(seed)
        task = encode(compiled, start, all_of(*goals.values()), forbidden, disabled)
        hmax, blind = solve(task, (Search.OPTIMAL, Search.BLIND))
        assert (hmax.plan is None) == (blind.plan is None), f"seed {seed}"
        assert hmax.plan is None or blind.plan is None or len(hmax.plan) == len(blind.plan), f"seed {seed}"


FLAT_SEEDS = range(40)  # 8 of them with a plan (1 to 4 steps)


@pytest.mark.parametrize("copies", [COPIES, 1], ids=["copies", "chains"])
def test_every_optimal_search_on_the_flat_task_finds_the_axioms_optimum(copies: int) -> None:
    """The flat flavour (no derived predicates) is the same task: blind search, lm-cut, merge-and-shrink and iPDB
    on it find plans as long as h^max on the derived predicates, valid under statehub's semantics; with
    `copies=1` every disjunctive condition goes through the action's chain of checks (on the stations the long
    race checks and synthesized guards do; random models have few)."""
    with_plan = 0
    for seed in FLAT_SEEDS:
        compiled, start, goals, forbidden, disabled = random_task(seed)
        goal = all_of(*goals.values())
        task = encode(compiled, start, goal, forbidden, disabled)
        (hmax,) = solve(task, (Search.OPTIMAL,))
        flat = solve(task, (Search.BLIND, Search.LMCUT, Search.MERGE_AND_SHRINK, Search.IPDB), flavour=Flavour.FLAT,
                     copies=copies)
        for search, answer in zip((Search.BLIND, Search.LMCUT, Search.MERGE_AND_SHRINK, Search.IPDB), flat,
                                  strict=True):
            assert (answer.plan is None) == (hmax.plan is None), f"seed {seed}, {search.name}: {answer.plan}"
            if answer.moves is not None and hmax.plan is not None:
                assert len(answer.moves) == len(hmax.plan), f"seed {seed}, {search.name}: {answer.plan}, {hmax.plan}"
                plan = read_back(compiled, start, answer, goals)
                validate_plan(compiled, start, plan, goal, forbidden, disabled)
        with_plan += hmax.plan is not None
    assert with_plan >= 8, "the seeds give 8 models with a plan: fewer says the generator changed"


def test_the_flat_task_refuses_nothing_lm_cut_refuses() -> None:
    """No derived predicates, disjunctions or conditional effects in the flat files (lm-cut would refuse the first
    and the last; the translator would split the second)."""
    compiled = CompiledModel(Generator(random.Random(3)).problem()[0].model)
    task = encode(compiled, compiled.initial(), all_of(*(Eq(p, v) for p, v in zip(compiled.paths[:1],
                                                                               compiled.initial()[:1], strict=True))))
    domain, _ = render(task, Flavour.FLAT)
    assert ":derived" not in domain and "(or " not in domain and "(when " not in domain
    assert "(increase (total-cost) 1)" in domain


def test_no_step_comes_between_an_actions_chain_of_checks_and_the_action() -> None:
    """A chain's checks hold only while the state stays: every step of statehub's either ends its own chain or
    needs no chain running (`busy` false); a check-free search on random models would rarely notice."""
    chains = 0
    for seed in FAST_SEEDS:
        compiled, start, goals, forbidden, disabled = random_task(seed)
        flattener = Flattener(encode(compiled, start, all_of(*goals.values()), forbidden, disabled), copies=1)
        flat = flattener.flatten()
        ends = set(flattener.chain_flags)
        for step in flat.steps:
            if step.origin is None:
                continue
            own_chain = [lit for lit in step.precondition if lit.positive and lit.atom in ends]
            assert own_chain or Literal(flattener.busy, False) in step.precondition, f"seed {seed}: {step.name}"
            chains += bool(own_chain)
    assert chains, "no action of these models has a chain: the check would test nothing"


# --- the stations' hard goal sets ------------------------------------------------------------------------------
# Lengths checked against Fast Downward's optimum where its A* finishes: h^max on the derived predicates and lm-cut on
# the flat task. On the others its satisficing plans are checked valid and no shorter than statehub's shortest,
# because no optimal configuration finished within 4-5 minutes on this machine (docs/pddl.md): on the flat task
# lm-cut starts at 47 of shared_workspace's 88 steps and at 16 of TightenBolt7's 27 and raises its bound by one
# in 10 s and 5 s, then not again in 100 s and 90 s (a chain of check states per enabled action, lm-cut on
# 2,600 and 21,700 operators in each); merge-and-shrink, iPDB and blind search time out too; the reference
# station's longer sets need more layers still.
OPTIMAL_STATION_CASES = ("machine_tending: 1 goals at start",)
# Every station's goal sets but the 24 bolts (241 steps: SymK's layers take 10-15 s each by the 106th, docs/pddl.md):
# SymK on the SAS+ task shows their optimum. On the 24 bolts it shows it on a projection of the task (below).
SYMBOLIC_STATION_CASES = ("machine_tending: 1 goals at start", "shared_workspace: 9 goals at start",
                          "TightenBolt7 (filter tool at home)", "Park+AttachFilterTool+3 filters+2 pipes",
                          "RobotHome (where it stalled)")
# Where `Planner.plan` answers without showing its plan shortest (a greedy plan of 88 steps, A* not done in 30 s),
# statehub's symbolic member shows it: its breadth-first layers make the first plan it finds a shortest one.
SHOWN_BY_THE_SYMBOLIC_MEMBER = ("shared_workspace: 9 goals at start",)
STATION_CASES = ("24 bolts (frame placed)",)


@functools.cache
def station_cases() -> dict[str, object]:
    from tests.bench.bench_planner import reference_cases
    from tests.bench.bench_planner import station_cases as other_stations

    return {case.name: case for case in (*other_stations(), *reference_cases())}


@pytest.mark.slow
@pytest.mark.parametrize("name", OPTIMAL_STATION_CASES)
def test_fast_downward_agrees_on_a_stations_goal_set(name: str) -> None:
    """(The validator reads the station's export in `test_the_export_without_axioms_is_valid_pddl_...`: 17 s.)"""
    from tests.bench.bench_planner import Case

    case = station_cases()[name]
    assert isinstance(case, Case)
    check_agreement(case.compiled, case.start, dict(case.goals), case.forbidden, frozenset(), case.name,
                    seconds=600.0)


def statehubs_shortest(case: Case) -> int:
    """The length of the plan statehub shows shortest for the case."""
    goals = dict(case.goals)
    planner = Planner(case.compiled, case.forbidden)
    if case.name in SHOWN_BY_THE_SYMBOLIC_MEMBER:
        member = planner.symbolic(frozenset())
        assert member is not None
        found = member.search(case.start, all_of(*goals.values()), deadline=time.perf_counter() + 600)
        assert found.moves is not None, f"{case.name}: statehub's symbolic member finds no plan ({found.reason})"
        return len(found.moves)
    ours = planner.plan(case.start, goals, frozenset(), budget=until_shown_shortest(600.0))
    assert isinstance(ours, Plan), f"{case.name}: statehub finds no plan ({ours.reason})"
    assert ours.stats.minimal, f"{case.name}: statehub did not show its plan shortest"
    return len(ours.steps)


@pytest.mark.slow
@pytest.mark.parametrize("name", SYMBOLIC_STATION_CASES)
def test_symk_finds_the_optimum_statehub_shows_on_a_stations_goal_set(name: str) -> None:
    """An optimal planner statehub did not write agrees on every station's goal sets: SymK's optimum on the SAS+
    task is as long as statehub's shortest plan, and SymK's plan and Fast Downward's satisficing one, read back as
    statehub steps, are valid under the engine's semantics."""
    from tests.bench.bench_planner import Case

    case = station_cases()[name]
    assert isinstance(case, Case)
    goals = dict(case.goals)
    goal = all_of(*goals.values())
    task = encode(case.compiled, case.start, goal, case.forbidden, frozenset())
    symbolic, satisficing = solve(task, (Search.SYMBOLIC, Search.SATISFICING), timeout=600, flavour=Flavour.SAS)
    shortest = statehubs_shortest(case)
    assert symbolic.moves is not None, f"{name}: statehub plans {shortest} steps, SymK shows there is no plan"
    assert len(symbolic.moves) == shortest, (
        f"{name}: SymK's optimum is {len(symbolic.moves)} steps ({', '.join(symbolic.plan or ())}), statehub shows "
        f"{shortest} shortest")
    assert satisficing.moves is not None and len(satisficing.moves) >= shortest, (
        f"{name}: Fast Downward's satisficing plan {satisficing.plan} against statehub's shortest {shortest}")
    for answer in (symbolic, satisficing):
        validate_plan(case.compiled, case.start, read_back(case.compiled, case.start, answer, goals), goal,
                      case.forbidden, frozenset())


@pytest.mark.slow
@pytest.mark.parametrize("name", STATION_CASES)
def test_fast_downwards_plans_are_valid_and_no_shorter_on_a_stations_goal_set(name: str) -> None:
    from tests.bench.bench_planner import Case

    case = station_cases()[name]
    assert isinstance(case, Case)
    check_satisficing(case.compiled, case.start, dict(case.goals), case.forbidden, frozenset(), case.name,
                      seconds=600.0)


# --- the task relaxed onto some variables: a lower bound where the whole task is too big ---------------------------
@pytest.mark.parametrize("seed", FAST_SEEDS)
def test_a_projection_onto_every_variable_is_the_task_itself(seed: int) -> None:
    compiled, start, goals, forbidden, disabled = random_task(seed)
    task = encode(compiled, start, all_of(*goals.values()), forbidden, disabled)
    assert render_sas(project(task, compiled, compiled.paths)) == render_sas(task)


def test_symk_on_a_projection_never_finds_a_plan_shorter_than_the_optimum() -> None:
    """The projection is a relaxation: on random models and random sets of kept variables SymK's optimum there is
    never above statehub's shortest on the whole task, and is found wherever the whole task has a plan; on every
    variable it is the shortest itself. And it does relax: somewhere it is shorter."""
    rng = random.Random(7)
    seen = {"equal": 0, "shorter": 0}
    for seed in range(40):
        compiled, start, goals, forbidden, disabled = random_task(seed)
        ours = Planner(compiled, forbidden).plan(start, goals, disabled, budget=until_shown_shortest(30.0))
        if not isinstance(ours, Plan):
            continue
        assert ours.stats.minimal, f"random model seed {seed}: statehub did not show its plan shortest"
        task = encode(compiled, start, all_of(*goals.values()), forbidden, disabled)
        keep = rng.sample(compiled.paths, rng.randint(1, len(compiled.paths)))
        (whole,), (relaxed,) = (solve(t, (Search.SYMBOLIC,), timeout=120, flavour=Flavour.SAS)
                                for t in (task, project(task, compiled, keep)))
        assert whole.moves is not None and len(whole.moves) == len(ours.steps), f"random model seed {seed}"
        assert relaxed.moves is not None and len(relaxed.moves) <= len(ours.steps), (
            f"random model seed {seed}: SymK's optimum on the variables {sorted(keep)} is {relaxed.plan}, longer "
            f"than statehub's shortest on the whole task ({len(ours.steps)} steps)")
        seen["equal" if len(relaxed.moves) == len(ours.steps) else "shorter"] += 1
    assert seen["equal"] >= 5 and seen["shorter"] >= 1, seen


@pytest.mark.slow
def test_symk_shows_the_24_bolts_shortest_on_the_variables_statehubs_plan_writes() -> None:
    """The one goal set no optimal planner finishes on the whole task (docs/pddl.md): SymK's optimum on the task
    relaxed onto the variables statehub's plan writes is a lower bound, and it is as long as statehub's plan,
    which is valid on the whole task. So that plan is shortest, shown by a planner statehub did not write."""
    from tests.bench.bench_planner import Case

    case = station_cases()["24 bolts (frame placed)"]
    assert isinstance(case, Case)
    goals = dict(case.goals)
    goal = all_of(*goals.values())
    ours = Planner(case.compiled, case.forbidden).plan(case.start, goals, frozenset(),
                                                       budget=until_shown_shortest(600.0))
    assert isinstance(ours, Plan), f"24 bolts: statehub finds no plan ({ours.reason})"
    validate_plan(case.compiled, case.start, ours, goal, case.forbidden, frozenset())
    keep = plan_variables(case.compiled, ours, goal)
    assert len(keep) < len(case.compiled.paths) / 2  # a projection, and the reason SymK finishes
    task = project(encode(case.compiled, case.start, goal, case.forbidden, frozenset()), case.compiled, keep)
    (relaxed,) = solve(task, (Search.SYMBOLIC,), timeout=900, flavour=Flavour.SAS)
    assert relaxed.moves is not None, "24 bolts: SymK shows no plan on the projection"
    assert len(relaxed.moves) == len(ours.steps) == 241, (
        f"24 bolts: SymK's optimum on the variables the plan writes is {len(relaxed.moves)} steps, statehub's plan "
        f"{len(ours.steps)}")


# --- what the encoding refuses -----------------------------------------------------------------------------------
def unvalidated(*transitions: Transition) -> CompiledModel:
    variables = (command("r.a_c"), command("r.n_c", Domain.range(0, 3)), measured("r.small_m", Domain.range(0, 1)))
    holder = ability("r.odd")
    holder = type(holder)(holder.name, holder.predicates, transitions)
    return CompiledModel(Model("odd", (Resource("r", variables, (holder,)),), validate_on_init=False))


def test_an_automatic_transition_with_alternative_outcomes_is_refused_by_name() -> None:
    both = Transition("r.either", TransitionKind.AUTOMATIC, Eq("r.a_c", False),
                      ((Assign("r.a_c", True),), (Assign("r.n_c", 2),)))
    compiled = unvalidated(both)
    with pytest.raises(Unexpressible, match=r"automatic transition r\.either has 2 alternative outcomes"):
        encode(compiled, compiled.initial(), Eq("r.a_c", True))


def test_a_copy_that_can_leave_the_target_domain_is_refused_by_name() -> None:
    compiled = unvalidated(deliberate("r.copy", "!r.a_c", [Assign("r.small_m", Ref("r.n_c"))]))
    with pytest.raises(Unexpressible, match=r"transition r\.copy: the copy r\.small_m := r\.n_c can write 2"):
        encode(compiled, compiled.initial(), Eq("r.small_m", 1))


def test_a_start_value_outside_its_domain_is_refused_by_name() -> None:
    compiled = unvalidated(deliberate("r.go", "!r.a_c", "r.a_c := true"))
    start = compiled.with_values(compiled.initial(), {"r.n_c": 7})
    with pytest.raises(Unexpressible, match=r"r\.n_c = 7 is outside its domain"):
        encode(compiled, start, Eq("r.a_c", True))


# --- hubctl export pddl --------------------------------------------------------------------------------------------
MACHINE_TENDING = str(Path(__file__).resolve().parents[1] / "examples" / "machine_tending" / "hubs.toml")


def test_export_writes_a_domain_and_problem_fast_downward_solves(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from controller.pddl.downward import run_files

    assert hubctl(["export", "pddl", "--out", str(tmp_path), "--config", MACHINE_TENDING]) == 0
    assert "goals: FeedPart1" in capsys.readouterr().out
    [plan] = run_files(tmp_path / "domain.pddl", tmp_path / "problem.pddl", (Search.SATISFICING,), tmp_path)
    assert plan, "Fast Downward found no plan for FeedPart1"


def test_export_writes_a_sas_task_symk_solves_optimally(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from controller.pddl.downward import run_sas

    assert hubctl(["export", "pddl", "FeedPart1", "--out", str(tmp_path), "--config", MACHINE_TENDING, "--sas"]) == 0
    assert f"wrote {tmp_path / 'output.sas'}" in capsys.readouterr().out
    symbolic, satisficing = run_sas(tmp_path / "output.sas", (Search.SYMBOLIC, Search.SATISFICING), tmp_path)
    assert symbolic is not None and len(symbolic) == 4, f"SymK's plan for FeedPart1: {symbolic}"
    assert satisficing is not None and len(satisficing) >= 4


def test_the_export_without_axioms_is_valid_pddl_and_fast_downwards_plan_valid_in_the_validator(
        tmp_path: Path) -> None:
    """A station's export as `hubctl export pddl --no-axioms` writes it: the validator reads it, and finds Fast
    Downward's plan valid in it under PDDL's own semantics (the plan found on the export with derived predicates,
    which Fast Downward translates in a second where the conditions written out take it minutes)."""
    inline, axioms, checked = tmp_path / "inline", tmp_path / "axioms", tmp_path / "checked"
    checked.mkdir()
    for out, flags in ((inline, ["--no-axioms"]), (axioms, [])):
        assert hubctl(["export", "pddl", "FeedPart1", "--out", str(out), "--config", MACHINE_TENDING, *flags]) == 0
    (plan,) = run_files(axioms / "domain.pddl", axioms / "problem.pddl", (Search.SATISFICING,), axioms, timeout=300)
    assert plan, "Fast Downward finds no plan for machine_tending's FeedPart1"
    validate_in_pyval(((inline / "domain.pddl").read_text(), (inline / "problem.pddl").read_text()), checked, plan)


def test_export_errors_name_the_goal_and_the_state_key(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert hubctl(["export", "pddl", "NoSuchOperation", "--out", str(tmp_path), "--config", MACHINE_TENDING]) == 2
    error = capsys.readouterr().err
    assert "goal 'NoSuchOperation' is neither an operation of machine_tending nor a predicate" in error
    state = tmp_path / "state.toml"
    state.write_text('"ur.nowhere_m" = 3\n')
    assert hubctl(["export", "pddl", "--out", str(tmp_path), "--config", MACHINE_TENDING, "--from", str(state)]) != 0
    assert "ur.nowhere_m" in capsys.readouterr().err
    assert not (tmp_path / "domain.pddl").exists()
