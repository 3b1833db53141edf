"""`hubctl timeline [RUN] [--out FILE.html|.svg|.png]` and `hubctl runs [DIR]`; `timeline_after_run` for `hubctl up`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from common.config.hubs_toml import ConfigError
from controller.recording.reader import RecordingError, list_runs, open_run
from controller.recording.writer import recording_dir

PLANS_PRINTED = 20


def default_directory(config: str | None) -> Path:
    """The station's recording dir: `[controller.recording] dir` of hubs.toml (or the default)."""
    from deploy.local.recordings import recording_settings

    return recording_dir(recording_settings(config or "hubs.toml").dir)


def draw_timeline(recording: str | Path, out: str | Path | None = None) -> tuple[Path, list[str]]:
    """Draw the run recorded in `recording` into `out` (default: next to it, .html); the file and a summary."""
    from controller.timeline.model import build_timeline
    from controller.timeline.render import plan_lines, render

    recording = Path(recording)
    target = Path(out) if out is not None else recording.with_suffix(".html")
    with open_run(recording) as run:
        timeline = build_timeline(run)
    render(timeline, target)
    lines = [f"{len(timeline.lanes)} lanes: {len(timeline.abilities)} ability spans, {len(timeline.operation_spans)} "
             f"operation states, {len(timeline.plans)} plans, {len(timeline.unhealthy)} unhealthy periods, "
             f"{len(timeline.faults)} faults"]
    if timeline.note:
        lines.append(timeline.note)
    return target, lines + plan_lines(timeline, PLANS_PRINTED)


def timeline_after_run(recording: Path, say: Callable[[str], object] = print) -> Path | None:
    """What `hubctl up` does when its run ended: the timeline next to the recording, and its path said."""
    try:
        target, _ = draw_timeline(recording)
    except Exception as exc:  # the run is over and recorded: a chart that cannot be drawn must not fail it
        say(f"timeline: not drawn: {type(exc).__name__}: {exc}")
        return None
    say(f"timeline: {target} (hubctl timeline {recording} --out FILE.png for a picture)")
    return target


def cmd_timeline(args: argparse.Namespace) -> int:
    run = args.run
    if run is None:
        runs = [r for r in list_runs(default_directory(args.config)) if not r.problem]
        if not runs:
            print(f"hubctl timeline: no recorded run in {default_directory(args.config)}", file=sys.stderr)
            return 2
        run = runs[-1].path
    try:
        target, lines = draw_timeline(run, args.out)
    except (RecordingError, ValueError) as exc:
        print(f"hubctl timeline: {exc}", file=sys.stderr)
        return 2
    print(f"timeline of {run}: {target}")
    for line in lines:
        print(f"  {line}")
    return 0


def cmd_runs(args: argparse.Namespace) -> int:
    from .listing import runs_table

    try:
        directory = Path(args.dir) if args.dir else default_directory(args.config)
    except ConfigError as exc:
        print(f"hubctl runs: {exc}", file=sys.stderr)
        return 2
    lines = runs_table(directory)
    if len(lines) == 1:
        print(f"no recorded run in {directory}")
        return 0
    print("\n".join(lines))
    return 0


def register_run_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    timeline = sub.add_parser("timeline", help="draw a recorded run as a Gantt chart (HTML, SVG or PNG)")
    timeline.add_argument("run", metavar="RUN", nargs="?",
                          help="a recording (default: the newest in the station's recording dir)")
    timeline.add_argument("--out", metavar="FILE", help="FILE.html (default, next to RUN), FILE.svg or FILE.png")
    timeline.add_argument("--config", help="the station's hubs.toml, for its recording dir (default: ./hubs.toml)")
    timeline.set_defaults(func=cmd_timeline)
    runs = sub.add_parser("runs", help="list the recorded runs, newest first, with their outcome")
    runs.add_argument("dir", metavar="DIR", nargs="?",
                      help="where the runs are recorded (default: [controller.recording] dir of hubs.toml)")
    runs.add_argument("--config", help="the station's hubs.toml (default: ./hubs.toml)")
    runs.set_defaults(func=cmd_runs)
