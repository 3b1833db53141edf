"""Controller persistence: values survive a reopen; stale or foreign rows are reported, not restored."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from common.model import Domain, Model, Resource, command, estimated, measured
from controller.state import StateStore


def small_model() -> Model:
    return Model("small", (Resource("nr", (command("nr.run_c", initial=False), measured("nr.run_m"))),),
                 estimated=(estimated("engine.bolt1_e", Domain.enum("loose", "tightened"), "loose"),))


def test_values_survive_reopening(tmp_path: Path) -> None:
    db = tmp_path / "state.sqlite"
    store = StateStore(db)
    store.save({"engine.bolt1_e": "tightened", "nr.run_c": True}, {"requested": ["A", "B"]})
    store.close()
    again = StateStore(db)
    values, notes = again.load(small_model())
    assert values == {"engine.bolt1_e": "tightened", "nr.run_c": True}
    assert notes == []
    assert again.meta("requested") == ["A", "B"]
    assert again.has_state()


def test_values_the_model_does_not_accept_are_reported(tmp_path: Path) -> None:
    store = StateStore(tmp_path / "state.sqlite")
    store.save({"engine.bolt2_e": "tightened", "engine.bolt1_e": "glued"})
    values, notes = store.load(small_model())
    assert values == {}
    assert any("engine.bolt2_e is not in model" in n for n in notes)
    assert any("engine.bolt1_e='glued' is outside" in n for n in notes)


def test_the_state_is_synced_at_every_commit(tmp_path: Path) -> None:
    store = StateStore(tmp_path / "state.sqlite")
    assert store.db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


WRITER = """
import sys
from controller.state import StateStore
store = StateStore(sys.argv[1])
for n in range(1_000_000):
    store.save({"engine.bolt1_e": "tightened" if n % 2 else "loose"}, {"saves": n})
    print(n, flush=True)
    if n >= 50:
        sys.stdin.readline()  # hold here: the parent kills us right after this save returned
"""


def test_a_save_that_returned_survives_kill_9(tmp_path: Path) -> None:
    """Power-cut style: the writer is killed -9 right after a save returned; the reopened database has it."""
    db = tmp_path / "state.sqlite"
    child = subprocess.Popen([sys.executable, "-c", WRITER, str(db)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    last = -1
    while last < 50:
        last = int(child.stdout.readline())
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    store = StateStore(db)
    assert store.meta("saves") == last
    values, _ = store.load(small_model())
    assert values == {"engine.bolt1_e": "loose" if last % 2 == 0 else "tightened"}
