"""The nutrunner: one tightening ability, exactly the paper's table (Example 4).

| predicate name | predicate                        | control actions          | effects                           |
|----------------|----------------------------------|--------------------------|-----------------------------------|
| enabled        | !run_c && !run_m                 | run_c := T (deliberate)  | -                                 |
| starting       | run_c && !run_m                  | -                        | run_m := T                        |
| executing      | run_c && run_m && !tqr_m && !fail_m | -                     | tqr_m := T, or fail_m := T        |
| finished       | run_c && run_m && (tqr_m || fail_m) | run_c := F (automatic) | -                                 |
| resetting      | !run_c && run_m                  | -                        | run_m := F, tqr_m := F, fail_m := F |
"""

from __future__ import annotations

from common.model import Duration, Phase, Resource, ability, command, measured

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# A tightening step: the spindle starting, the torque (or the failure), the spindle stopping.
DURATION = Duration.fixed(0.12)


def nutrunner(name: str = "nr") -> Resource:
    run_c = command(f"{name}.run_c", initial=False, description="run the spindle")
    run_m = measured(f"{name}.run_m", description="the spindle runs")
    tqr_m = measured(f"{name}.tqr_m", description="the target torque was reached")
    fail_m = measured(f"{name}.fail_m", description="the tightening failed")
    tighten = ability(
        f"{name}.tighten",
        enabled=Phase(~run_c & ~run_m, deliberate=f"{run_c.path} := true"),
        starting=Phase(run_c & ~run_m, effects=[f"{run_m.path} := true"]),
        executing=Phase(run_c & run_m & ~tqr_m & ~fail_m,
                        effects=[f"{tqr_m.path} := true", f"{fail_m.path} := true"]),
        finished=Phase(run_c & run_m & (tqr_m | fail_m), automatic=f"{run_c.path} := false"),
        resetting=Phase(~run_c & run_m,
                        effects=[[f"{run_m.path} := false", f"{tqr_m.path} := false", f"{fail_m.path} := false"]]),
    )
    return Resource(name, (run_c, run_m, tqr_m, fail_m), (tighten,), device_type="nutrunner")
