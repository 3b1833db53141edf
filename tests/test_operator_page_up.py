"""`hubctl up` with the operator in mode real: `--real human` runs that one device real while the rest of
the station stays as hubs.toml (or --mode) says, and `up` prints the operator's page's address."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config.hubs_toml import load_station
from common.config.modes import DeviceMode
from deploy.cli import main as hubctl
from deploy.local.operator_pages import operator_pages
from deploy.local.station import Options, child_commands
from hubs.drivers.emulated import EmulatedDriver
from hubs.drivers.operator_page.address import needs_a_token, page_url
from hubs.drivers.operator_page.driver import OperatorPage
from hubs.drivers.operator_page.params import OperatorPageParams
from hubs.factory import build_drivers
from tests.operator_page_support import ROOT

REFERENCE = ROOT / "hubs.toml"
TOKEN = "panel-token-0123456789+/"


@pytest.mark.parametrize(("host", "tls", "url"), [
    ("0.0.0.0", False, "http://127.0.0.1:8080/"),  # bound everywhere: reached on loopback here
    ("::", False, "http://[::1]:8080/"),
    ("192.168.1.7", True, "https://192.168.1.7:8080/"),
    ("fe80::1", False, "http://[fe80::1]:8080/"),
    ("decs.local", False, "http://decs.local:8080/"),
])
def test_the_page_s_address_for_a_browser_on_the_hub_s_machine(host: str, tls: bool, url: str) -> None:
    assert page_url(OperatorPageParams(host=host), tls=tls) == url


def test_the_address_carries_the_panel_s_token_and_says_when_it_needs_one() -> None:
    with_panel = OperatorPageParams(tokens={"panel": TOKEN, "watch": "watch-token-0123456789"})
    assert page_url(with_panel, tls=False) == "http://127.0.0.1:8080/?token=panel-token-0123456789%2B%2F"
    assert not needs_a_token(with_panel)
    watch_only = OperatorPageParams(tokens={"watch": "watch-token-0123456789"})
    assert page_url(watch_only, tls=False) == "http://127.0.0.1:8080/"  # the watch's token is not the panel's
    assert needs_a_token(watch_only)
    assert not needs_a_token(OperatorPageParams())


def test_up_serves_a_page_only_for_an_operator_that_runs_real(tmp_path: Path) -> None:
    config, _ = load_station(REFERENCE)
    assert operator_pages(config, None, ()) == []  # the reference station: every device emulated
    assert operator_pages(config, DeviceMode.SIM, ()) == []  # the operator has no simulator: emulated
    [page] = operator_pages(config, None, {"human"})
    assert (page.resource, page.hub, page.url) == ("human", "human", "http://127.0.0.1:8080/")
    assert page.line() == "operator's page (human on hub human): http://127.0.0.1:8080/"
    assert [p.url for p in operator_pages(config, DeviceMode.SIM, {"human"})] == ["http://127.0.0.1:8080/"]
    # mode = "real" in hubs.toml does the same, and a page with tokens but no panel's says what to add
    text = REFERENCE.read_text().replace('type = "operator"\nmode = "emulate"', 'type = "operator"\nmode = "real"')
    text = text.replace("# tokens = { panel", 'tokens = { watch = "watch-token-0123456789" } # { panel')
    (tmp_path / "hubs.toml").write_text(text)
    config, _ = load_station(tmp_path / "hubs.toml")
    [page] = operator_pages(config, None, ())
    assert page.needs_token and "add ?token=TOKEN" in page.line()


def test_real_reaches_only_the_hub_of_that_device() -> None:
    config, model = load_station(REFERENCE)
    children = {c.name: c.argv for c in child_commands(config, Options(real=frozenset({"human"})), 7447)}
    assert children["human"][-2:] == ["--real", "human"]
    assert all("--real" not in argv for name, argv in children.items() if name != "human")
    drivers = build_drivers(config, "human", model, real={"human"})
    assert isinstance(drivers["human"], OperatorPage)
    # --real beats --mode: the rest follows --mode
    assert isinstance(build_drivers(config, "human", model, mode=DeviceMode.EMULATE, real={"human"})["human"],
                      OperatorPage)
    assert isinstance(build_drivers(config, "human", model)["human"], EmulatedDriver)
    with pytest.raises(ValueError, match="hub 'human' serves no such device"):
        build_drivers(config, "human", model, real={"ur"})


def test_up_refuses_a_real_device_it_does_not_have_and_real_in_one_process(capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["up", "--config", str(REFERENCE), "--real", "nobody"]) == 2
    assert "--real nobody: " in capsys.readouterr().err
    assert hubctl(["up", "--in-process", "--real", "human"]) == 2
    assert "not --in-process" in capsys.readouterr().err
