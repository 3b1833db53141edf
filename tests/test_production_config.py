"""Where orders come from: [production] in hubs.toml and `hubctl up --orders N --mix ...`, checked."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config.hubs_toml import ConfigError, load_station, parse_config
from common.config.production import ProductionConfig, ProductionError, parse_mix, plan_from_options
from common.stations.engine_assembly import build_model
from common.wire.orders import OrdersAction
from deploy.cli import build_parser
from deploy.orders_cli import request_of

ROOT = Path(__file__).resolve().parent.parent


def _station(tmp_path: Path, production: str) -> Path:
    path = tmp_path / "hubs.toml"
    path.write_text((ROOT / "hubs.toml").read_text(encoding="utf-8") + "\n" + production, encoding="utf-8")
    return path


def _line_of(path: Path, text: str) -> int:
    return next(n for n, line in enumerate(path.read_text().splitlines(), start=1) if line.startswith(text))


def test_a_mix_in_hubs_toml_repeats_its_pattern(tmp_path: Path) -> None:
    config, model = load_station(_station(tmp_path, "[production]\nmix = { full = 2, light = 1 }\ncount = 5\n"))
    plan = plan_from_options(None, None, config.production, model, config.path)
    assert plan is not None
    assert [o.variant for o in plan.orders] == ["full", "full", "light", "full", "full"]
    assert plan.describe().startswith("5 orders (4 full, 1 light) from ")


def test_a_list_of_orders_in_hubs_toml(tmp_path: Path) -> None:
    text = ('[production]\n[[production.orders]]\nvariant = "light"\nproduct_id = "E-1"\n'
            'parameters = { "engine.count_bolts_e" = 22 }\n[[production.orders]]\nvariant = "full"\ncount = 2\n')
    config, model = load_station(_station(tmp_path, text))
    plan = plan_from_options(None, None, config.production, model, config.path)
    assert plan is not None
    assert [(o.variant, o.product_id) for o in plan.orders] == [("light", "E-1"), ("full", ""), ("full", "")]
    assert plan.orders[0].parameters == {"engine.count_bolts_e": 22}


@pytest.mark.parametrize(("production", "line_starts", "message"), [
    ("[production]\nmix = { full = 3 }\n", "[production]", "production.count: a mix needs count"),
    ("[production]\nmix = { full = 0 }\ncount = 2\n", "mix =", "production.mix: Expected `int` >= 1"),
    ("[production]\nmix = { full = 1 }\ncount = 2\nbatch = 3\n", "batch", "production.batch: unknown key"),
    ('[production]\n[[production.orders]]\nvariant = "full"\n[[production.orders]]\nvarient = "light"\n',
     "varient", "production.orders[1]: Object contains unknown field `varient`"),
])
def test_production_errors_name_file_line_and_key(tmp_path: Path, production: str, line_starts: str,
                                                  message: str) -> None:
    path = _station(tmp_path, production)
    with pytest.raises(ConfigError) as error:
        load_station(path)
    problem = error.value.problems[0]
    assert message in str(problem) and problem.file == str(path)
    expected = _line_of(path, line_starts)
    if line_starts == "varient":  # an order table's problem is at its table's header
        expected = [n for n, line in enumerate(path.read_text().splitlines(), start=1)
                    if line.startswith("[[production.orders]]")][1]
    assert problem.line == expected


def test_production_against_the_model_names_the_variant(tmp_path: Path) -> None:
    path = _station(tmp_path, "[production]\nmix = { full = 1, heavy = 2 }\ncount = 3\n")
    with pytest.raises(ConfigError) as error:
        load_station(path)
    problem = error.value.problems[0]
    assert problem.key == "production.mix.heavy" and "has no variant 'heavy' (its variants: full, light)" in str(
        problem)
    assert problem.line == _line_of(path, "mix =")
    text = path.read_text().replace("mix = { full = 1, heavy = 2 }\ncount = 3\n",
                                    '[[production.orders]]\nvariant = "light"\nparameters = { "engine.frame_e" = 1 }\n')
    with pytest.raises(ConfigError, match=r"production.orders\[0\]: variant light has no parameter engine.frame_e"):
        parse_config(text, str(path), model=build_model())


def test_up_options_win_over_hubs_toml_and_are_checked() -> None:
    model = build_model()
    from_file = ProductionConfig(mix={"light": 1}, count=9)
    plan = plan_from_options(3, "full:1,light:2", from_file, model, "hubs.toml")
    assert plan is not None and [o.variant for o in plan.orders] == ["full", "light", "light"]
    plan = plan_from_options(2, None, from_file, model, "hubs.toml")
    assert plan is not None and [o.variant for o in plan.orders] == ["light", "light"]
    plan = plan_from_options(2, None, ProductionConfig(), model, "hubs.toml")
    assert plan is not None and [o.variant for o in plan.orders] == ["full", "full"]  # the model's first
    assert plan_from_options(None, None, ProductionConfig(), model, "hubs.toml") is None  # runs as today
    with pytest.raises(ProductionError, match="--mix needs --orders N"):
        plan_from_options(None, "full:1", from_file, model, "hubs.toml")
    with pytest.raises(ProductionError, match="has no variant 'heavy'"):
        plan_from_options(2, "heavy:1", from_file, model, "hubs.toml")
    with pytest.raises(ProductionError, match="--orders 0: give 1 to"):
        plan_from_options(0, None, from_file, model, "hubs.toml")


@pytest.mark.parametrize(("text", "message"), [
    ("full:x", "'full:x' is not VARIANT or VARIANT:WEIGHT"),
    ("full:0", "the weight of full must be at least 1"),
    ("full,full:2", "full is given twice"),
])
def test_a_bad_mix_says_which_item(text: str, message: str) -> None:
    assert parse_mix("full:3, light") == {"full": 3, "light": 1}
    with pytest.raises(ProductionError, match=message):
        parse_mix(text)


def test_hubctl_parses_up_orders_and_the_orders_command() -> None:
    parser = build_parser()
    args = parser.parse_args(["up", "--orders", "5", "--mix", "full:3,light:1"])
    assert (args.orders, args.mix) == (5, "full:3,light:1")
    args = parser.parse_args(["orders", "add", "light", "--count", "2", "--param", "engine.count_bolts_e=22"])
    request = request_of(args, "me@here")
    assert (request.action, request.variant, request.count, request.parameters) == (
        OrdersAction.ADD, "light", 2, {"engine.count_bolts_e": 22})
    assert request_of(parser.parse_args(["orders", "cancel", "3"]), "me").order == 3
    assert request_of(parser.parse_args(["orders", "list", "--all"]), "me").include_finished
    with pytest.raises(SystemExit):
        parser.parse_args(["orders", "add", "light", "--param", "engine.count_bolts_e"])
