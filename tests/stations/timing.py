"""Small stations for time in the model: durations declared by a station's own types, and one per timing
hazard that `hubctl check` names (controller/timing_hazards.py), plus one with none.

`feeder_station` is issue 21's smallest station that livelocks: a robot `r`, a vacuum gripper `g` and a
feeder `f` whose "box taken" sensor registers only while the robot stays at the feeder with its vacuum on.
"""

from __future__ import annotations

from common.model import (
    Duration,
    Model,
    Phase,
    Resource,
    ability,
    all_of,
    command,
    estimated,
    measured,
    operation,
    tracking,
)
from common.model.variables import Domain
from common.resources import nutrunner, ur

VACUUM_DURATION = Duration.fixed(0.1)  # the gripper's own type declares it; the feeder's declares none


def vacuum_gripper(name: str = "g") -> Resource:
    vac_c = command(f"{name}.vac_c", initial=False, description="suck")
    vac_m = measured(f"{name}.vac_m", description="vacuum built up")
    grip = ability(f"{name}.grip",
                   enabled=Phase(~vac_c & ~vac_m, deliberate=f"{vac_c.path} := true"),
                   starting=Phase(vac_c & ~vac_m, effects=[f"{vac_m.path} := true"]),
                   finished=vac_c & vac_m)
    release = ability(f"{name}.release",
                      enabled=Phase(vac_c & vac_m, deliberate=f"{vac_c.path} := false"),
                      starting=Phase(~vac_c & vac_m, effects=[f"{vac_m.path} := false"]),
                      finished=~vac_c & ~vac_m)
    return Resource(name, (vac_c, vac_m), (grip, release), device_type="vacuum_gripper", duration=VACUUM_DURATION)


def box_feeder(name: str = "f", robot: str = "r", gripper: str = "g") -> Resource:
    feed_c = command(f"{name}.feed_c", initial=False, description="feed the next box")
    present_m = measured(f"{name}.present_m", initial=True, description="a box is on the feeder")
    feed = ability(f"{name}.feed",
                   enabled=Phase(~feed_c & ~present_m, deliberate=f"{feed_c.path} := true"),
                   starting=Phase(feed_c & ~present_m, effects=[f"{present_m.path} := true"]),
                   finished=Phase(feed_c & present_m, automatic=f"{feed_c.path} := false"))
    taken = ability(f"{name}.taken",
                    executing=Phase(all_of(present_m, ~feed_c, f"{robot}.pos_m == at_feeder", f"{gripper}.vac_m"),
                                    effects=[f"{present_m.path} := false"]))
    return Resource(name, (feed_c, present_m), (feed, taken), device_type="box_feeder")


def feeder_station() -> Model:
    robot = ur("r", ("home", "at_feeder", "at_pallet"),
               (("home", "at_feeder"), ("at_feeder", "at_pallet"), ("at_pallet", "home")))
    box = estimated("cell.box_e", Domain.enum("waiting", "on_feeder", "held", "on_pallet"), "waiting", "the box")
    boxes = (
        tracking("cell.box_arrives", "cell.box_e == waiting && f.present_m", "cell.box_e := on_feeder"),
        tracking("cell.box_held", "cell.box_e == on_feeder && !f.present_m && g.vac_m", "cell.box_e := held"),
        tracking("cell.box_placed", "cell.box_e == held && r.pos_m == at_pallet && !g.vac_m",
                 "cell.box_e := on_pallet"),
    )
    place = operation("Place", "cell.box_e != on_pallet", "cell.box_e == on_pallet")
    return Model("feeder_cell", (robot, vacuum_gripper(), box_feeder()), (box,), boxes, (place,))


def sensed_device_station() -> Model:
    """A sensor that sees the robot at the feeder only while it stays there: commands move it away."""
    robot = ur("r", ("home", "at_feeder"), (("home", "at_feeder"),))
    seen_m = measured("f.seen_m", description="the robot was seen at the feeder")
    sees = ability("f.sees", executing=Phase(~seen_m & "r.pos_m == at_feeder", effects=["f.seen_m := true"]))
    sensor = Resource("f", (seen_m,), (sees,), device_type="presence_sensor")
    return Model("sensed_device", (robot, sensor))


def command_disables_station() -> Model:
    """A conveyor that may be stopped while a part is on its way: the stop disables the arrival."""
    run_c = command("c.run_c", initial=False, description="run the belt")
    at_m = measured("c.at_m", description="a part is at the end of the belt")
    run = ability("c.run",
                  enabled=Phase(~run_c & ~at_m, deliberate="c.run_c := true"),
                  executing=Phase(run_c & ~at_m, effects=["c.at_m := true"]),
                  finished=run_c & at_m)
    stop = ability("c.stop", enabled=Phase(run_c, deliberate="c.run_c := false"))
    clear = ability("c.clear", executing=Phase(~run_c & at_m, effects=["c.at_m := false"]))
    conveyor = Resource("c", (run_c, at_m), (run, stop, clear), device_type="conveyor", duration=Duration(0.5, 1.0))
    return Model("command_disables", (conveyor,))


def transient_station() -> Model:
    """A light barrier whose pulse fades by itself, counted by tracking that needs the pulse."""
    trigger_c = command("s.trigger_c", initial=False, description="arm the barrier")
    pulse_m = measured("s.pulse_m", description="the beam was interrupted")
    pulse = ability("s.pulse",
                    enabled=Phase(~trigger_c & ~pulse_m, deliberate="s.trigger_c := true"),
                    starting=Phase(trigger_c & ~pulse_m, effects=["s.pulse_m := true"]),
                    finished=Phase(trigger_c & pulse_m, automatic="s.trigger_c := false"))
    fade = ability("s.fade", executing=Phase(pulse_m, effects=["s.pulse_m := false"]))
    barrier = Resource("s", (trigger_c, pulse_m), (pulse, fade), device_type="light_barrier",
                       duration=Duration.fixed(0.05))
    counted = estimated("cell.counted_e", initial=False, description="a part was counted")
    count = tracking("cell.count", "s.pulse_m && !cell.counted_e", "cell.counted_e := true")
    return Model("transient", (barrier,), (counted,), (count,))


def safe_station() -> Model:
    """The nutrunner and tracking of its result: nothing races."""
    done = estimated("cell.done_e", initial=False, description="the bolt is tightened")
    record = tracking("cell.tightened", "nr.tqr_m && !cell.done_e", "cell.done_e := true")
    tighten = operation("Tighten", "!cell.done_e", "cell.done_e")
    return Model("safe", (nutrunner("nr"),), (done,), (record,), (tighten,))
