"""`hubctl rollback HUB`: run the release that was current before the current one.

"Before" comes from the release log on the target (`/opt/statehub/releases.log`): the
`previous` of the newest deploy of the current release. A second rollback therefore
walks one more deploy back instead of toggling; `--to RELEASE` picks any complete
release on the target. The switch is the deploy's: the release's own unit back in
place, `current` renamed over, a restart that reverts when it fails.
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from common.config.hubs_toml import load_config

from . import scripts
from .deploy import (
    Connection,
    DeployFailed,
    Waiting,
    check_hub,
    failure_text,
    hub_watch,
    now,
    read_station_file,
    restart_step,
    target_of,
    wait_step,
    who,
)
from .layout import Layout, hub_unit_name
from .progress import Progress, StepFailed
from .ssh import Remote, RemoteError

ROLLBACK_STEPS = 5


@dataclass(frozen=True)
class RollbackOptions:
    config: Path
    hub: str
    to: str | None = None
    connection: Connection = field(default_factory=Connection)
    waiting: Waiting = field(default_factory=Waiting)


class NothingToRollBackTo(RuntimeError):
    pass


def choose_release(history: scripts.History, hub: str, to: str | None, where: str, log_path: str) -> str:
    available = ", ".join(history.releases) or "none"
    if to is not None:
        if to not in history.releases:
            raise NothingToRollBackTo(f"release {to!r} is not a complete release on {where} (there: {available})")
        return to
    if history.current is None:
        raise NothingToRollBackTo(f"hub {hub} has no current release on {where}: deploy it first")
    previous = scripts.previous_release(history.log, hub, history.current)
    if previous is None:
        raise NothingToRollBackTo(f"{log_path} on {where} has no release of hub {hub} before {history.current} "
                                  f"(complete releases there: {available}; pick one with --to)")
    if previous not in history.releases:
        raise NothingToRollBackTo(f"the release before {history.current}, {previous}, is gone from {where} "
                                  f"(complete releases there: {available}; pick one with --to)")
    return previous


async def rollback(opts: RollbackOptions, out: TextIO | None = None) -> None:
    """Raises DeployFailed with the step, the host, the remote error and the state left behind."""
    conn, hub, unit = opts.connection, opts.hub, hub_unit_name(opts.hub)
    progress = Progress(ROLLBACK_STEPS, out=out, dry_run=conn.dry_run)
    layout = Layout(conn.root)
    where, current, target_release = "this machine", None, "<previous release>"
    try:
        async with progress.step(f"check {opts.config}", always=True) as note:
            read_station_file(opts.config)
            config = await asyncio.to_thread(load_config, opts.config)
            check_hub(config, hub)
            settings = config.hubs[hub]
            note.detail = f"hub {hub} on {settings.ssh_user}@{settings.host}"
        target = target_of(config, hub, conn)
        async with Remote(target, dry_run=conn.dry_run, sudo=conn.sudo, show=progress.show_command) as remote:
            where = target.where
            async with progress.step(f"read the release log on {where}") as note:
                result = await remote.run(scripts.read_log(layout, hub), what="read the release log")
                if not conn.dry_run:
                    history = scripts.parse_history(result.stdout)
                    remote.remote_uid = history.uid
                    current = history.current
                    target_release = choose_release(history, hub, opts.to, where, layout.release_log)
                    note.detail = f"current {current}, rolling back to {target_release}"

            async with contextlib.AsyncExitStack() as stack:
                async with progress.step(f"switch current to {target_release} on {target.host}") as note:
                    # The watch opens first: should it fail, nothing has switched.
                    watch = await stack.enter_async_context(
                        hub_watch(config, hub, Waiting(wait=False) if conn.dry_run else opts.waiting))
                    log = scripts.log_line(hub=hub, action="rollback", release=target_release, previous=current,
                                           by=who(), time=now())
                    try:
                        await remote.run(scripts.activate(layout, hub, target_release, unit, log),
                                         what="switch current", privileged=True)
                    except RemoteError as exc:
                        raise RemoteError(exc.where, exc.what, exc.returncode,
                                          f"{exc.stderr}\ncurrent may still be {current}: check `readlink "
                                          f"{layout.current(hub)}` on the target") from exc
                    note.detail = f"{current} -> {target_release}"
                await restart_step(progress, remote, layout, hub, target_release, current, watch)
                await wait_step(progress, watch, hub, opts.waiting)
    except StepFailed as exc:
        # Steps 3 and 4 say themselves where they left `current`.
        state = ("nothing on the target was changed" if exc.number <= 2
                 else "" if exc.number <= 4 else f"current is {target_release} and its unit was restarted")
        raise DeployFailed(failure_text("rollback", hub, exc, where, state)) from exc
