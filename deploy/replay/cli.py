"""`hubctl replay RUN [--save-test tests/replays/NAME]`."""

from __future__ import annotations

import argparse
import sys

from controller.recording.reader import RecordingError, open_run


def cmd_replay(args: argparse.Namespace) -> int:
    # Imported here, not at the top: every hubctl command builds this parser, and the replay brings the
    # controller's planner (BDDs, networkx), ~0.3 s of CPU that `hubctl selftest` on a hub has no use for.
    from .replay import Replayer, ReplayError

    try:
        with open_run(args.run) as run:
            result = Replayer(run).replay()
            if result.same and args.save_test:
                from .savetest import save_test

                saved = save_test(run, args.save_test)
    except (RecordingError, ReplayError) as exc:
        print(f"hubctl replay: {exc}", file=sys.stderr)
        return 2
    counts = ", ".join(f"{n} {kind}" for kind, n in sorted(result.decisions.items())) or "none"
    if result.divergence is not None:
        print(f"replay of {args.run}: {result.records} records; the same decisions until here ({counts})")
        print(result.divergence)
        if args.save_test:
            print("not saved as a test: a saved run must replay to the same decisions")
        return 1
    print(f"replay of {args.run}: {result.records} records, the same decisions ({counts})")
    if result.cut_short:
        print(f"the recording ends abruptly (its controller was killed): {result.cut_short} decisions replayed at its "
              f"last instant were not recorded")
    if args.save_test:
        print(f"saved as a test: {saved} (tests/test_replays.py replays it)")
    return 0


def register_replay_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    replay = sub.add_parser("replay", help="replay a recorded run on a fresh controller and check it decides the "
                                           "same (plans, commands, operation transitions)")
    replay.add_argument("run", metavar="RUN", help="a recording (var/runs/*.sqlite by default)")
    replay.add_argument("--save-test", metavar="PATH",
                        help="store the trimmed run (PATH.sqlite, e.g. tests/replays/NAME) for the suite to replay")
    replay.set_defaults(func=cmd_replay)
