"""Product variants in the model: declaration, validation, the soundness of a selection, the reference station."""

from __future__ import annotations

import pytest

from common.model import (
    DEFAULT_VARIANT,
    Domain,
    Model,
    ModelError,
    Operation,
    Resource,
    command,
    estimated,
    measured,
    operation,
    tracking,
    variant,
)
from common.model.variants import implies
from common.stations.engine_assembly import OPERATION_ORDER, build_model


def _model(*variants: object, product: tuple[str, ...] = ("part.*",), extra: tuple[Operation, ...] = ()) -> Model:
    """Two parts; `Finish` waits for part b unless the part count says the product has only part a."""
    states = Domain.enum("absent", "done")
    return Model(
        "parts",
        (Resource("arm", (command("arm.go_c", initial=False), measured("arm.at_m"))),),
        tracking=(tracking("part.a_done", "arm.at_m && arm.go_c", "part.a_e := done"),
                  tracking("part.b_done", "arm.at_m && !arm.go_c", "part.b_e := done")),
        estimated=(estimated("part.a_e", states, "absent"), estimated("part.b_e", states, "absent"),
                   estimated("part.count_e", Domain.range(1, 2), 2), estimated("cell.mode_e", Domain.enum("x"), "x")),
        operations=(
            operation("DoA", "part.a_e == absent", "part.a_e == done"),
            operation("DoB", "part.b_e == absent", "part.b_e == done"),
            operation("Finish", "part.a_e == done && (part.b_e == done || part.count_e == 1)", "arm.at_m"),
            *extra,
        ),
        product=product,
        variants=tuple(variants),  # type: ignore[arg-type]  # the cases pass Variants; object keeps the helper short
    )


def test_a_model_without_variants_has_one_implicit_variant_of_every_operation() -> None:
    model = _model()
    assert list(model.variant_by_name) == [DEFAULT_VARIANT]
    assert model.variant_by_name[DEFAULT_VARIANT].requested(model.operations) == ("DoA", "DoB", "Finish")
    # the product: the estimated variables the patterns name, then every operation's state
    assert model.product_variables == ("part.a_e", "part.b_e", "part.count_e", "op.DoA", "op.DoB", "op.Finish")


def test_a_variant_may_leave_out_what_its_parameters_make_unneeded() -> None:
    model = _model(variant("two"), variant("one", ["DoA", "Finish"], {"part.count_e": 1}))
    assert model.variant_by_name["one"].requested(model.operations) == ("DoA", "Finish")
    assert model.variant_by_name["one"].parameters == {"part.count_e": 1}


@pytest.mark.parametrize(("variants", "message"), [
    ((variant("one", ["DoA", "Finish"]),),
     "variant one: operation Finish needs the goal of DoB, which the variant leaves out: nothing would reach "
     "part.b_e == done, so Finish would never start"),
    ((variant("one", ["DoA", "Fnish"]),), "variant one: unknown operation Fnish"),
    ((variant("one"), variant("one")), "variant one: duplicate variant name"),
    ((variant("one", parameters={"cell.mode_e": "x"}),),
     "variant one: parameter cell.mode_e is not a product variable of the model"),
    ((variant("one", parameters={"part.count_e": 3}),), "variant one: parameter part.count_e = 3 is outside"),
    ((variant("one", parameters={"part.a_e": "done"}),),
     "variant one: parameter part.a_e is written by a transition: a parameter holds for the whole order"),
    ((variant("not a name"),), "a variant's name must be an identifier"),
])
def test_variant_problems_are_reported_with_the_variant_and_why(variants: tuple[object, ...], message: str) -> None:
    with pytest.raises(ModelError) as error:
        _model(*variants)
    assert message in str(error.value)


def test_a_product_pattern_that_matches_nothing_is_reported() -> None:
    with pytest.raises(ModelError, match=r"product engine\.\*: matches no estimated variable"):
        _model(product=("engine.*",))


def test_implication_is_read_from_conjunctions_of_comparisons_only() -> None:
    variables = _model().variables
    from common.model import parse_predicate as p

    assert implies(p("part.a_e == done && part.count_e == 2"), p("part.a_e != absent"), variables)
    assert implies(p("part.count_e in {2}"), p("part.count_e == 1 || part.count_e == 2"), variables)
    assert not implies(p("part.a_e == done || part.b_e == done"), p("part.a_e == done"), variables)
    assert not implies(p("part.a_e != absent"), p("part.b_e == done"), variables)


def test_the_reference_station_declares_full_and_light_and_full_is_every_operation() -> None:
    model = build_model()
    assert list(model.variant_by_name) == ["full", "light"]
    full, light = model.variant_by_name["full"], model.variant_by_name["light"]
    assert full.requested(model.operations) == OPERATION_ORDER
    left_out = set(OPERATION_ORDER) - set(light.requested(model.operations))
    assert left_out == {"TightenBolt21", "TightenBolt22", "TightenBolt23", "TightenBolt24", "MountFilter3",
                        "TightenFilter3", "MountOilPipes", "TightenPipe1", "TightenPipe2"}
    assert dict(light.parameters) == {"engine.count_bolts_e": 20, "engine.count_filters_e": 2,
                                      "engine.count_pipes_e": 0}
    assert "engine.bolt24_e" in model.product_variables and "op.AgvLeave" in model.product_variables


def test_the_reference_station_leaves_agv_leave_waiting_only_for_the_parts_a_variant_takes() -> None:
    model = build_model()
    agv_leave = model.operation_by_name["AgvLeave"].pre
    done = {**model.initial_state(), "ur.pos_m": "home"}
    for k in (1, 2):
        done[f"engine.filter{k}_e"] = "tightened"
    for i in range(1, 21):
        done[f"engine.bolt{i}_e"] = "tightened"
    assert not agv_leave.eval(done)  # full: bolts 21-24, filter 3 and the pipes are still missing
    assert agv_leave.eval({**done, **model.variant_by_name["light"].parameters})


def test_the_reference_stations_light_variant_would_be_unsound_without_its_parameters() -> None:
    model = build_model()
    light = model.variant_by_name["light"]
    with pytest.raises(ModelError, match="operation ParkNutrunner needs the goal of TightenBolt21"):
        Model(model.name, model.resources, model.estimated, model.tracking, model.operations,
              model.specifications, product=model.product, variants=(variant("light", light.operations),))
