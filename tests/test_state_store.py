"""Controller persistence: values survive a reopen; stale or foreign rows are reported, not restored."""

from __future__ import annotations

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
