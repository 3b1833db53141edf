"""A robot with jobs to do one at a time and an operator who needs one of them (controller/retime.py).

Robot `r` does jobs a and b (and, `warm_up`, first job w, which a and b need), each round trip of its command
`r.job_c` from `none` and back; operator `o` works once job b is done. Every order of a and b is a shortest
plan; the planner's own choice does a first, so the operator waits for both jobs. Done b first, the operator
works beside job a. Written with `common.model` only, as a station outside this repository would be.
"""

from __future__ import annotations

from common.model import Ability, Domain, Duration, Model, Phase, Resource, ability, command, measured, operation

ROBOT_S, OPERATOR_S = 3.0, 5.0


def _job(name: str, after: str | None) -> Ability:
    flag = f"r.{name}_m"
    needs = f" && r.{after}_m" if after else ""
    return ability(f"r.do_{name}", enabled=Phase(f"r.job_c == none && !{flag}{needs}", deliberate=f"r.job_c := {name}"),
                   executing=Phase(f"r.job_c == {name} && !{flag}", effects=f"{flag} := true"),
                   done=Phase(f"r.job_c == {name} && {flag}", deliberate="r.job_c := none"))


def goal(warm_up: bool = False) -> str:
    return "r.a_m && r.b_m && o.on_m && r.job_c == none" + (" && r.w_m" if warm_up else "")


def build_model(warm_up: bool = False, robot_s: float = ROBOT_S, operator_s: float = OPERATOR_S) -> Model:
    """`warm_up`: job w comes first (over Zenoh, the planner's improvements arrive while the robot does it)."""
    jobs = ("w", "a", "b") if warm_up else ("a", "b")
    job_c = command("r.job_c", Domain.enum("none", *jobs), "none")
    flags = tuple(measured(f"r.{name}_m") for name in jobs)
    abilities = tuple(_job(name, "w" if warm_up and name != "w" else None) for name in jobs)
    robot = Resource("r", (job_c, *flags), abilities, device_type="job_robot", duration=Duration.fixed(robot_s))
    work = ability("o.work", enabled=Phase("!o.on_c && !o.on_m && r.b_m", deliberate="o.on_c := true"),
                   executing=Phase("o.on_c && !o.on_m", effects="o.on_m := true"))
    operator = Resource("o", (command("o.on_c"), measured("o.on_m")), (work,), device_type="bench_operator",
                        duration=Duration.fixed(operator_s))
    return Model("two_jobs", (robot, operator), operations=(operation("Work", "!o.on_m", goal(warm_up)),))


def with_warm_up() -> Model:
    return build_model(warm_up=True, robot_s=1.0, operator_s=1.6)
