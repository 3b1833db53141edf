"""`hubctl test` against the operator's hub in mode real (the operator's page, deploy/modeltest): a simulated
operator presses Confirm through the page's endpoint with its token whenever the page allows, and the
generated tests pass; without it nobody presses, and the test finds the confirmation the model expects
missing (so the passing run is the page confirming where the model says, not a test that cannot fail)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import free_port
from deploy.modeltest.simulated_operator import NoOperatorPage, page_access
from tests.fault_station.harness import ROOT, write_config
from tests.hub_process import HubProcess

WATCH = "watch-token-0123456789"
PANEL = "panel-token-0123456789"


def operator_station(directory: Path, page_port: int, tokens: str = f'{{ watch = "{WATCH}" }}') -> Path:
    """The reference hubs.toml, the operator's page on `page_port` of loopback with `tokens`."""
    return write_config(directory, ROOT / "hubs.toml", prefix="opmodeltest", replace=[
        ("port = 8080", f"port = {page_port}"), ('host = "0.0.0.0"', 'host = "127.0.0.1"'),
        ('# tokens = { panel = "...", watch = "..." }', f"tokens = {tokens}")])


def hubctl_test(config: Path, port: int, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "deploy.modeltest.cli", "test", "human", "--config", str(config),
                           "--loopback-port", str(port), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=240)


@pytest.fixture
def operator_hub(tmp_path: Path, hub_process: Callable[..., HubProcess]) -> tuple[Path, int]:
    """The operator's hub as a process, its device in mode real (`--real human`): its page serves."""
    config, port = operator_station(tmp_path, free_port()), free_port()
    hub_process(config, "human", port, "--real", "human")
    return config, port


@pytest.mark.slow
def test_hubctl_test_passes_the_operator_s_page_with_a_simulated_operator(operator_hub: tuple[Path, int]) -> None:
    config, port = operator_hub
    result = hubctl_test(config, port, "--simulated-operator", "watch", "--examples", "8")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "PASSED 8 examples" in result.stdout and "human: passed" in result.stdout
    taken = result.stdout.split("token of watch): ", 1)[1].split(" presses taken", 1)[0]
    assert int(taken) > 0, result.stdout  # the page confirmed, from its endpoint


@pytest.mark.slow
def test_without_anyone_pressing_the_test_finds_the_confirmation_missing(operator_hub: tuple[Path, int]) -> None:
    config, port = operator_hub
    result = hubctl_test(config, port, "--examples", "10", "--max-steps", "3", "--deadline", "1", "--seed", "1")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "effect not observed" in result.stdout and "expected  human.done_m := true" in result.stdout


@pytest.mark.slow
def test_a_token_the_page_does_not_have_is_refused_before_testing(operator_hub: tuple[Path, int]) -> None:
    config, port = operator_hub
    result = hubctl_test(config, port, "--simulated-operator", "panel")
    assert result.returncode == 2, result.stdout + result.stderr
    assert "no token for device 'panel'" in result.stdout


def test_which_token_the_simulated_operator_presses_with(tmp_path: Path) -> None:
    two = operator_station(tmp_path, 18080, f'{{ watch = "{WATCH}", panel = "{PANEL}" }}')
    config, _ = load_station(two)
    access = page_access(config, "human", "panel")
    assert (access.url, access.token, access.device) == ("http://127.0.0.1:18080/", PANEL, "panel")
    with pytest.raises(NoOperatorPage, match="name the device whose token"):
        page_access(config, "human", None)
    with pytest.raises(NoOperatorPage, match="is no operator device"):
        page_access(config, "ur", None)
    config, _ = load_station(operator_station(tmp_path, 18080, "{}"))
    assert page_access(config, "human", None).token == ""  # a page without tokens takes any press
