"""Fast Downward on an exported task, and its plan read back as statehub moves.

Fast Downward comes from the PyPI wheel `up-fast-downward` (the planner binary inside), SymK (a symbolic
planner built on Fast Downward) from `up-symk`; both are test dependencies: statehub never needs them to run,
only to be checked against independent planners.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from controller.planner.steps import Move

from .encoding import Task
from .flat import COPIES, flatten, render_flat
from .sas import render_sas
from .writer import Flavour, render


class Search(Enum):
    """Fast Downward's search configurations used here.

    OPTIMAL, BLIND and SATISFICING accept derived predicates; hmax is admissible on the axioms flavour
    because its derived predicates occur only positively (the delete relaxation with axioms is a
    relaxation). LMCUT, MERGE_AND_SHRINK and IPDB refuse axioms and conditional effects: they run on the
    flat flavour (`flat.py`), where every search is optimal in cost = statehub's length."""

    OPTIMAL = "astar(hmax())"
    BLIND = "astar(blind())"  # optimal too, no heuristic: the cross-check of OPTIMAL on small tasks
    SATISFICING = "lazy_greedy([ff()], preferred=[ff()])"
    LMCUT = "astar(lmcut())"
    MERGE_AND_SHRINK = ("astar(merge_and_shrink(shrink_strategy=shrink_bisimulation(greedy=false),"
                        "merge_strategy=merge_sccs(order_of_sccs=topological,merge_selector=score_based_filtering("
                        "scoring_functions=[goal_relevance(),dfp(),total_order()])),"
                        "label_reduction=exact(before_shrinking=true,before_merging=false),max_states=50000,"
                        "threshold_before_merge=1))")
    IPDB = "astar(ipdb())"
    # SymK's bidirectional symbolic uniform-cost search (BDDs, as statehub's symbolic member): optimal, and the one
    # optimal search that finishes on the reference station's goal sets. Only on the SAS+ flavour, whose
    # multi-valued variables it needs (through the translator's binary facts it builds no transition relation in
    # 10 minutes); Gamer's variable ordering spends its 30 s limit on the derived variables and gains nothing here.
    SYMBOLIC = "sym_bd(gamer_ordering=false)"

    @property
    def optimal(self) -> bool:
        return self is not Search.SATISFICING


FLAT_ONLY = frozenset({Search.LMCUT, Search.MERGE_AND_SHRINK, Search.IPDB})
SAS_ONLY = frozenset({Search.SYMBOLIC})


class DownwardError(RuntimeError):
    """Fast Downward failed for a reason other than finding no plan (input error, time or memory)."""


@dataclass(frozen=True)
class Answer:
    plan: tuple[str, ...] | None  # action names; None: proven unsolvable
    moves: tuple[Move, ...] | None


UNSOLVABLE = (10, 11)  # TRANSLATE_UNSOLVABLE, SEARCH_UNSOLVABLE (driver/returncodes.py)
INCOMPLETE = 12  # SEARCH_UNSOLVED_INCOMPLETE: how SymK ends a search that exhausted the state space
# SymK's last lower bound when both frontiers ran dry: no plan of any length (its "infinity", INT_MAX).
SYMK_EXHAUSTED = "BOUND: 2147483647 < 2147483647"


def binaries() -> Path:
    """The directory of Fast Downward's search binary and its translator package, as the wheel installs them."""
    spec = importlib.util.find_spec("up_fast_downward")
    if spec is None or spec.origin is None:
        raise DownwardError("Fast Downward is not installed: pip install up-fast-downward (in statehub's test extras)")
    return Path(spec.origin).parent / "downward" / "builds" / "release" / "bin"


def symk_binary() -> Path:
    """SymK's search binary, as the `up-symk` wheel installs it."""
    spec = importlib.util.find_spec("up_symk")
    if spec is None or spec.origin is None:
        raise DownwardError("SymK is not installed: pip install up-symk (in statehub's test extras)")
    return Path(spec.origin).parent / "symk" / "builds" / "release" / "bin" / "downward"


def _call(command: list[str], workdir: Path, timeout: float, what: str, stdin: Path | None = None,
          exhausted: str | None = None) -> int:
    """The component's exit code: 0 (a plan), or one of UNSOLVABLE (shown to have none; also INCOMPLETE when the
    output says `exhausted`); anything else raises DownwardError with the output's end."""
    # The components are called as the wheel's driver (fast-downward.py) calls them, without the driver's own
    # interpreter start per call: on a small task those starts are most of the time.
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(binaries()),
                                                                                os.environ.get("PYTHONPATH"))))}
    with open(stdin) if stdin is not None else contextlib.nullcontext() as source:
        done = subprocess.run(command, cwd=workdir, capture_output=True, text=True, timeout=timeout, check=False,
                              env=environment, stdin=source)
    if done.returncode == INCOMPLETE and exhausted is not None and exhausted in done.stdout:
        return UNSOLVABLE[1]
    if done.returncode not in (0, *UNSOLVABLE):
        tail = "\n".join((done.stdout + done.stderr).splitlines()[-15:])
        raise DownwardError(f"fast-downward exited {done.returncode} on {what}:\n{tail}")
    return done.returncode


def run_files(domain: Path, problem: Path, searches: tuple[Search, ...], workdir: Path,
              timeout: float = 300.0) -> list[tuple[str, ...] | None]:
    """Per search, the plan (action names) Fast Downward finds for the files, or None when it shows there is none.
    The task is translated once (the translator, in Python, is most of the time on a small task)."""
    sas = workdir / "output.sas"
    # No invariant synthesis (mutex groups): on a station it is 90 % of the translator's time (37 s of 41 s CPU
    # on the reference station), and the searches used here do not need the groups (binary variables instead).
    translate = [sys.executable, "-m", "fast_downward.translate", str(domain), str(problem), "--sas-file", str(sas),
                 "--invariant-generation-max-candidates", "0"]
    if _call(translate, workdir, timeout, str(problem)):
        return [None for _ in searches]
    return run_sas(sas, searches, workdir, timeout)


def run_sas(sas: Path, searches: tuple[Search, ...], workdir: Path,
            timeout: float = 300.0) -> list[tuple[str, ...] | None]:
    """Per search, the plan Fast Downward (SymK for Search.SYMBOLIC) finds for a SAS+ file, or None for none."""
    plans: list[tuple[str, ...] | None] = []
    for search in searches:
        plan_file = workdir / f"plan-{search.name.lower()}"
        binary = symk_binary() if search is Search.SYMBOLIC else binaries() / "downward"
        command = [str(binary), "--search", search.value, "--internal-plan-file", str(plan_file)]
        code = _call(command, workdir, timeout, f"{sas} ({search.value})", stdin=sas,
                     exhausted=SYMK_EXHAUSTED if search is Search.SYMBOLIC else None)
        plans.append(None if code else read_plan(plan_file.read_text()))
    return plans


def read_plan(text: str) -> tuple[str, ...]:
    """Action names of a plan file: one `(name)` a line; `;` starts a comment (the cost line)."""
    names = []
    for line in text.splitlines():
        line = line.split(";", 1)[0].strip()
        if line:
            names.append(line.strip("()").split()[0].lower())
    return tuple(names)


def solve(task: Task, searches: tuple[Search, ...], timeout: float = 300.0,
          flavour: Flavour = Flavour.AXIOMS, copies: int = COPIES) -> list[Answer]:
    """Write the task (derived predicates, the flat flavour, or SAS+), run Fast Downward with each search on it and
    read each plan back as (transition number, outcome) moves."""
    refused = [s for s in searches if s in FLAT_ONLY and flavour is not Flavour.FLAT]
    if refused:
        raise DownwardError(f"{refused[0].value} refuses derived predicates: run it on Flavour.FLAT")
    refused = [s for s in searches if s in SAS_ONLY and flavour is not Flavour.SAS]
    if refused:
        raise DownwardError(f"{refused[0].value} needs the model's multi-valued variables: run it on Flavour.SAS")
    flat = flatten(task, copies) if flavour is Flavour.FLAT else None
    with tempfile.TemporaryDirectory(prefix="statehub-pddl-") as directory:
        workdir = Path(directory)
        if flavour is Flavour.SAS:
            (workdir / "output.sas").write_text(render_sas(task))
            plans = run_sas(workdir / "output.sas", searches, workdir, timeout)
        else:
            domain_text, problem_text = render_flat(flat) if flat is not None else render(task, flavour)
            (workdir / "domain.pddl").write_text(domain_text)
            (workdir / "problem.pddl").write_text(problem_text)
            plans = run_files(workdir / "domain.pddl", workdir / "problem.pddl", searches, workdir, timeout)
    if flat is not None:
        plans = [None if plan is None else flat.origins(plan) for plan in plans]
    moves = task.moves
    answers = []
    for plan in plans:
        if plan is None:
            answers.append(Answer(None, None))
            continue
        unknown = [name for name in plan if name not in moves]
        if unknown:
            raise DownwardError(f"the plan names action {unknown[0]!r}, not an action of the task")
        answers.append(Answer(plan, tuple(moves[name] for name in plan)))
    return answers
