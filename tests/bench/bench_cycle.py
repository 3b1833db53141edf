"""Cycle time of the reference station in process, plans executed as traces (before) and as partial orders
(after), with the bound the controller reports, and beside it the bound without the specifications' exclusions
(the larger of the run's causal chain and the busiest resource's work; controller/exclusions.py adds the rest):
`.venv/bin/python tests/bench/bench_cycle.py`."""

from __future__ import annotations

from common.stations import load_model
from controller.deorder import Execution
from deploy.local.inprocess import run_in_process

ISSUE_DELAYS = {"human": 20.0, "ur": 1.5, "nr": 2.0}  # issue 21: operator 20 s, ur 1.5 s, nr 2 s


def main() -> None:
    model = load_model()
    for label, delays in (("default delays", None), ("issue 21 delays", ISSUE_DELAYS)):
        for seed in (1, 2, 3):
            cells = []
            for execution in (Execution.TRACE, Execution.PARTIAL_ORDER):
                summary = run_in_process(model, seed=seed, delays=delays, execution=execution)
                cycle = summary.cycle
                assert cycle is not None and summary.finished, summary.reason
                causes = max(cycle.chain, cycle.busiest_work)
                cells.append(f"{execution.value}: cycle {cycle.cycle:6.1f} s bound {cycle.bound:6.1f} s "
                             f"ratio {cycle.ratio:4.2f} (without exclusions {causes:6.1f} s, "
                             f"{cycle.cycle / causes if causes else 0.0:4.2f})")
            print(f"{label:16} seed {seed}  " + "  |  ".join(cells))


if __name__ == "__main__":
    main()
