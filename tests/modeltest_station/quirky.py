"""A station with one nutrunner that behaves like the paper's real device, not like the paper's model.

The paper's model (`common.resources.nutrunner`) resets the torque-reached input when
the spindle stops (`resetting`: `tqr_m := false`). The real tool keeps it high until
the next run starts: `tqr_m := false` happens in `starting`. The hub of `quirky.toml`
emulates that device (its EmulatedDriver applies this model's effects), so that the
model-based test of the paper's model finds the difference.
"""

from __future__ import annotations

from common.model import Model, Phase, Resource, ability, command, measured


def quirky_nutrunner(name: str = "nr") -> Resource:
    """The device as it is: torque-reached resets only when run goes high again."""
    run_c = command(f"{name}.run_c", initial=False, description="run the spindle")
    run_m = measured(f"{name}.run_m", description="the spindle runs")
    tqr_m = measured(f"{name}.tqr_m", description="the target torque was reached")
    fail_m = measured(f"{name}.fail_m", description="the tightening failed")
    tighten = ability(
        f"{name}.tighten",
        enabled=Phase(~run_c & ~run_m, deliberate=f"{run_c.path} := true"),
        starting=Phase(run_c & ~run_m, effects=[[f"{run_m.path} := true", f"{tqr_m.path} := false"]]),
        executing=Phase(run_c & run_m & ~tqr_m & ~fail_m,
                        effects=[f"{tqr_m.path} := true", f"{fail_m.path} := true"]),
        finished=Phase(run_c & run_m & (tqr_m | fail_m), automatic=f"{run_c.path} := false"),
        resetting=Phase(~run_c & run_m, effects=[[f"{run_m.path} := false", f"{fail_m.path} := false"]]),
    )
    return Resource(name, (run_c, run_m, tqr_m, fail_m), (tighten,), device_type="nutrunner")


def build_model() -> Model:
    return Model("quirky_nutrunner_station", (quirky_nutrunner("nr"),))


def paper_model() -> Model:
    """The paper's nutrunner model (tqr reset in `resetting`), to hold the quirky device to: `--model`."""
    from common.resources import nutrunner

    return Model("paper_nutrunner", (nutrunner("nr"),))
