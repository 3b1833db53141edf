"""What the operator's page shows, computed from what the hub knows: one struct, pushed to the page as JSON.

The page (static/page.js) only renders this; every decision (who works here, the instruction, whether the
Confirm button is enabled and why not) is taken here, where it is tested without a browser too."""

from __future__ import annotations

import msgspec

from common.model import Value
from common.resources.operator import NO_TASK
from common.stations.instructions import InstructionTable

UNKNOWN_POSE = "unknown"  # the robot's `pos_m` between named poses: it moves


class PageView(msgspec.Struct, frozen=True, kw_only=True):
    resource: str
    verified: bool  # an operator is verified (badge scanned)
    operator: str  # the verified operator's name, "" when unknown or nobody
    greeting: str
    task: str  # the instruction standing (`instr_c`), "none" when there is none
    instruction: str  # its text in the page's language
    picture: str  # the picture's URL, "" when there is none
    step: int  # 1-based position of the task in the instruction table, 0 when none
    steps: int
    robot: str  # what the robot does now, "" when the page follows no robot
    robot_waits: bool  # the robot stands still while the operator has an instruction
    done: bool  # the button is pressed (done_m)
    can_confirm: bool
    reason: str  # why Confirm is disabled, in the console's words
    supervisor_called: bool
    abnormal: bool  # something the operator must see: shown in colour, the rest stays grey


class Badge(msgspec.Struct, frozen=True):
    verified: bool | None  # None: the page follows no badge reader (nobody needs to be verified)
    name: str = ""


def page_view(*, resource: str, values: dict[str, Value], refusal: str | None, badge: Badge,
              table: InstructionTable | None, language: str, robot: str, supervisor_called: bool) -> PageView:
    task = str(values[f"{resource}.instr_c"])
    done = bool(values[f"{resource}.done_m"])
    verified = badge.verified is not False
    step, steps, text, picture = 0, 0, "", ""
    if table is not None:
        steps = len(table.steps)
        found = table.step_of(task)
        if found is not None:
            step, instruction = found
            text = instruction.text_in(language)
            picture = f"pictures/{task}" if instruction.picture is not None else ""
    if task != NO_TASK and not text:
        text = task.replace("_", " ")  # a task the table does not know still shows what it is
    if task == NO_TASK:
        text = "No instruction: wait for the next task."
    robot_text, robot_waits = "", False
    if robot:
        pose, stopped = values.get(f"{robot}.pos_m"), values.get(f"{robot}.prot_stop_m")
        if stopped:
            robot_text = "Robot: protective stop"
        elif pose == UNKNOWN_POSE:
            robot_text = "Robot: moving"
        else:
            robot_text = f"Robot: stands at {str(pose).replace('_', ' ')}"
            robot_waits = task != NO_TASK and not done
        if robot_waits:
            robot_text += " and waits for you"
    if badge.verified is None:
        greeting = ""
    elif badge.verified:
        greeting = f"Welcome, {badge.name}" if badge.name else "Operator verified"
    else:
        greeting = "No operator verified: scan your badge"
    return PageView(
        resource=resource, verified=verified, operator=badge.name if badge.verified else "", greeting=greeting,
        task=task, instruction=text, picture=picture, step=step, steps=steps, robot=robot_text,
        robot_waits=robot_waits, done=done, can_confirm=refusal is None, reason=refusal or "",
        supervisor_called=supervisor_called,
        abnormal=supervisor_called or not verified or bool(values.get(f"{robot}.prot_stop_m")),
    )
