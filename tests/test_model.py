"""The modelling language: notation both ways, operators, validation, the paper's nutrunner."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.model import (
    FALSE,
    TRUE,
    And,
    Const,
    Domain,
    Eq,
    In,
    IsTrue,
    Model,
    ModelError,
    Ne,
    Not,
    Or,
    ParseError,
    Phase,
    Predicate,
    Ref,
    Resource,
    ability,
    command,
    deliberate,
    effect,
    estimated,
    measured,
    operation,
    parse_action,
    parse_predicate,
)
from common.model.compiled import CompiledModel

paths = st.sampled_from(["nr.run_c", "nr.run_m", "ur.pos_m", "engine.bolt1_e", "a.b_c"])
names = st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True).filter(lambda s: s not in ("true", "false", "in"))
values = st.one_of(st.booleans(), st.integers(-50, 50), names)
operands = st.one_of(values, paths.map(Ref))
atoms = st.one_of(
    st.booleans().map(Const),
    paths.map(IsTrue),
    st.builds(Eq, paths, operands),
    st.builds(Ne, paths, operands),
    st.builds(In, paths, st.lists(values, min_size=1, max_size=3).map(tuple)),
)
predicates = st.recursive(
    atoms,
    lambda inner: st.one_of(
        inner.map(Not),
        st.lists(inner, min_size=2, max_size=3).map(lambda xs: And(tuple(xs))),
        st.lists(inner, min_size=2, max_size=3).map(lambda xs: Or(tuple(xs))),
    ),
    max_leaves=12,
)


@given(predicates)
def test_printing_and_parsing_are_inverse(p: Predicate) -> None:
    assert parse_predicate(str(p)) == p


def test_operators_build_the_same_tree_as_text() -> None:
    run_c, run_m = command("nr.run_c", initial=False), measured("nr.run_m")
    pos = measured("ur.pos_m", Domain.enum("home", "at_bolt1"))
    built = run_c & ~run_m & (pos == "at_bolt1")
    assert built == parse_predicate("nr.run_c && !nr.run_m && ur.pos_m == at_bolt1")
    assert str(built) == "nr.run_c && !nr.run_m && ur.pos_m == at_bolt1"
    assert (run_c | run_m) == parse_predicate("nr.run_c || nr.run_m")
    assert (pos != "home") == Ne("ur.pos_m", "home")
    assert (pos == pos) == Eq("ur.pos_m", Ref("ur.pos_m"))


def test_precedence_and_parentheses() -> None:
    assert parse_predicate("a.x || a.y && a.z") == Or((IsTrue("a.x"), And((IsTrue("a.y"), IsTrue("a.z")))))
    assert parse_predicate("(a.x || a.y) && a.z") == And((Or((IsTrue("a.x"), IsTrue("a.y"))), IsTrue("a.z")))
    assert parse_predicate("!a.x == 3") == Not(Eq("a.x", 3))
    assert parse_predicate("a.x in {p, q, 4}") == In("a.x", ("p", "q", 4))
    assert parse_predicate("true") == TRUE and parse_predicate("false") == FALSE


@pytest.mark.parametrize(
    ("text", "column"),
    [("nr.run_c &&", 11), ("nr.run_c == ", 12), ("(nr.run_c", 9), ("nr.run_c ? x", 9), ("home == nr.x", 0)],
)
def test_syntax_errors_point_at_the_column(text: str, column: int) -> None:
    with pytest.raises(ParseError) as info:
        parse_predicate(text)
    assert info.value.column == column
    assert "^" in str(info.value)


def test_actions_parse_values_and_variables() -> None:
    assert str(parse_action("door.pos_e := door.refpos_c")) == "door.pos_e := door.refpos_c"
    assert parse_action("nr.run_c := true").value is True
    with pytest.raises(ParseError):
        parse_action("nr.run_c = true")


def nutrunner_resource(name: str = "nr") -> Resource:
    v = {n: measured(f"{name}.{n}") for n in ("run_m", "tqr_m", "fail_m")}
    run_c = command(f"{name}.run_c", initial=False)
    tighten = ability(
        f"{name}.tighten",
        enabled=Phase(~run_c & ~v["run_m"], deliberate=f"{name}.run_c := true"),
        starting=Phase(run_c & ~v["run_m"], effects=[f"{name}.run_m := true"]),
        executing=Phase(run_c & v["run_m"] & ~v["tqr_m"] & ~v["fail_m"],
                        effects=[f"{name}.tqr_m := true", f"{name}.fail_m := true"]),
        finished=Phase(run_c & v["run_m"] & (v["tqr_m"] | v["fail_m"]), automatic=f"{name}.run_c := false"),
        resetting=Phase(~run_c & v["run_m"],
                        effects=[[f"{name}.run_m := false", f"{name}.tqr_m := false", f"{name}.fail_m := false"]]),
    )
    return Resource(name, (run_c, *v.values()), (tighten,), device_type="nutrunner")


def test_the_papers_nutrunner_table() -> None:
    model = Model("nutrunner", (nutrunner_resource(),))
    a = model.abilities[0]
    assert str(a.predicates["enabled"]) == "!nr.run_c && !nr.run_m"
    assert str(a.predicates["finished"]) == "nr.run_c && nr.run_m && (nr.tqr_m || nr.fail_m)"
    kinds = {t.name: t.kind.value for t in a.transitions}
    assert kinds == {
        "nr.tighten.enabled": "deliberate",
        "nr.tighten.starting.effect": "effect",
        "nr.tighten.executing.effect": "effect",
        "nr.tighten.finished": "automatic",
        "nr.tighten.resetting.effect": "effect",
    }
    executing = a.transition("executing.effect")
    assert [str(a) for o in executing.outcomes for a in o] == ["nr.tqr_m := true", "nr.fail_m := true"]
    # One run through the table with the compiled semantics: finished resets run_c at once.
    c = CompiledModel(model)
    s = c.by_name["nr.tighten.enabled"].outcomes[0](c.initial())
    s = c.by_name["nr.tighten.starting.effect"].outcomes[0](s)
    s = c.by_name["nr.tighten.executing.effect"].outcomes[0](s)
    s, fired = c.close(s)
    assert [t.name for t in fired] == ["nr.tighten.finished"]
    assert c.unpack(s) == {"nr.run_c": False, "nr.run_m": True, "nr.tqr_m": True, "nr.fail_m": False}


def test_abilities_are_templates() -> None:
    poses = [f"p{i}" for i in range(5)]
    ref = command("r.ref_c", Domain.enum(*poses), "p0")
    pos = measured("r.pos_m", Domain.enum(*poses))
    moves = [ability(f"r.to_{p}", enabled=Phase(ref == pos, deliberate=f"r.ref_c := {p}"),
                     executing=Phase((ref == p) & (pos != p), effects=[f"r.pos_m := {p}"])) for p in poses]
    model = Model("templated", (Resource("r", (ref, pos), tuple(moves)),))
    assert len(model.ability_transitions) == 10


def door_model() -> Model:
    """The paper's door: an estimated position, a measured lock, a commanded reference position."""
    pos = estimated("door.pos_e", Domain.enum("closed", "opening", "open"), "closed")
    locked = measured("door.locked_m", initial=True)
    ref = command("door.refpos_c", Domain.enum("closed", "open"), "closed")
    door_open = ability(
        "door.open",
        enabled=Phase((pos == "closed") & ~locked & (ref == "closed"), deliberate="door.refpos_c := open"),
        executing=Phase((ref == "open") & (pos != "open"), automatic="door.pos_e := open"),
        finished=(ref == "open") & (pos == "open"),
    )
    unlock = ability("door.unlock", executing=Phase(locked, effects=["door.locked_m := false"]))
    return Model("door", (Resource("door", (pos, locked, ref), (door_open, unlock)),),
                 operations=(operation("OpenDoor", "door.pos_e == closed", "door.pos_e == open"),))


def test_the_papers_door() -> None:
    model = door_model()
    c = CompiledModel(model)
    s = c.initial()
    assert not c.by_name["door.open.enabled"].guard(s)  # locked
    s = c.by_name["door.unlock.executing.effect"].outcomes[0](s)
    s = c.by_name["door.open.enabled"].outcomes[0](s)
    s, fired = c.close(s)
    assert [t.name for t in fired] == ["door.open.executing"]
    assert c.unpack(s)["door.pos_e"] == "open"
    assert model.var("op.OpenDoor").initial == "initial"


def test_validation_reports_every_problem_with_path_and_expression() -> None:
    nr = nutrunner_resource()
    bad = ability(
        "nr.bad",
        enabled=Phase("nr.run_x && nr.run_c == 3", deliberate="nr.run_m := true"),
        extra=[effect("nr.bad.writes_command", "nr.run_m", ["nr.run_c := true"]),
               deliberate("nr.tighten.enabled", "true", "nr.run_c := false")],
    )
    broken = Resource("nr", nr.variables, (*nr.abilities, bad))
    with pytest.raises(ModelError) as info:
        Model("broken", (broken,), operations=(operation("Op", "nr.nope", "nr.run_c == blue"),))
    text = str(info.value)
    assert "nr.bad.enabled: unknown variable nr.run_x" in text
    assert "in: nr.run_x && nr.run_c == 3" in text
    assert "value 3 is outside the domain of nr.run_c (bool)" in text
    assert "writes measured variable nr.run_m" in text
    assert "effect writes command variable nr.run_c" in text
    assert "nr.tighten.enabled: duplicate transition name" in text
    assert "operation Op (pre): unknown variable nr.nope" in text
    assert "value 'blue' is outside the domain of nr.run_c" in text
    assert len(info.value.problems) == 7


def test_domains_keep_bools_and_ints_apart() -> None:
    assert True not in Domain.range(0, 3) and 1 not in Domain.boolean()
    with pytest.raises(ValueError):
        Domain.enum("true")
    with pytest.raises(ValueError):
        Domain.range(3, 1)
