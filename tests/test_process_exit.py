"""A process asked to stop ends: tasks that swallow their cancellation are cancelled again
(common/plumbing/tasks.py), and a process stuck anyway exits within its guard with every thread's stack
printed (common/plumbing/lifecycle.py `stop_on_signals`)."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from common.plumbing.tasks import cancel_and_wait

ROOT = Path(__file__).resolve().parents[1]


async def test_a_task_that_swallows_its_cancellation_is_cancelled_again() -> None:
    swallowed = 0

    async def stubborn() -> None:  # what 3.11's wait_for does when its future completes as the cancel comes
        nonlocal swallowed
        while True:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                swallowed += 1
                if swallowed >= 3:
                    raise

    task = asyncio.create_task(stubborn(), name="stubborn")
    await asyncio.sleep(0)
    assert await cancel_and_wait([task], 5.0) == []
    assert task.cancelled() and swallowed == 3


async def test_a_task_that_never_ends_is_named_and_left_behind_within_the_bound() -> None:
    released = False

    async def immortal() -> None:
        while True:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                if released:
                    raise

    async def polite() -> None:
        await asyncio.sleep(3600)

    stuck, ended = asyncio.create_task(immortal(), name="immortal"), asyncio.create_task(polite(), name="polite")
    await asyncio.sleep(0)
    began = time.monotonic()
    assert await cancel_and_wait([stuck, ended], 0.3) == ["immortal"]
    assert time.monotonic() - began < 5.0  # returns at its bound, not never
    assert ended.cancelled() and not stuck.done()
    released = True  # the test's own cleanup: the loop would wait for it at its close
    stuck.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await stuck


STUCK_PROCESS = textwrap.dedent("""
    import asyncio, sys, time
    from common.plumbing.lifecycle import stop_on_signals

    def hang_for_good() -> None:
        time.sleep(3600)  # a driver call that never returns, holding the loop

    async def main() -> None:
        stop = stop_on_signals(exit_within=1.0)
        print("ready", flush=True)
        await stop.wait()
        hang_for_good()

    asyncio.run(main())
""")


def test_a_process_stuck_after_sigterm_exits_within_its_guard_and_prints_where() -> None:
    process = subprocess.Popen([sys.executable, "-c", STUCK_PROCESS], cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None and process.stdout.readline().strip() == "ready"
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 1, stderr
    assert "Timeout" in stderr and "hang_for_good" in stderr, stderr


def test_a_process_that_used_zenoh_leaves_with_its_status_its_output_and_its_exit_handlers() -> None:
    """`exit_process` skips the interpreter's teardown, where zenoh's runtime threads calling into Python
    have aborted a finished `hubctl test` (status -6 instead of 1); what a process says and registers to
    do at exit still happens. Left to the teardown, a session still open holds the process for ever: the
    run below would time out."""
    script = textwrap.dedent("""
        import atexit, sys, zenoh
        from common.plumbing.lifecycle import exit_process
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
        session = zenoh.open(config)
        session.declare_subscriber("statehub/test/exit", lambda sample: None)
        atexit.register(lambda: print("exit handler ran"))
        print("said before leaving", end="")
        exit_process(1)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert result.returncode == 1, result.stderr
    assert result.stdout == "said before leavingexit handler ran\n"
