"""The process entry points: `python -m hubs`, `python -m controller`, and hubctl's commands that run them.

The station's own tests start real hubs and controllers through `python -m ...` (hubctl up,
the fault and sim stations); here: `hubctl hub`/`controller`/`selftest` are the same
commands, and an operator's mistake is one line naming the process, not a traceback.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from deploy.cli import main as hubctl

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "hubs.toml"


def run(*argv: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(a) for a in argv], cwd=ROOT, capture_output=True, text=True, timeout=60)


def test_a_hubs_self_test_is_the_same_from_every_entry_point(capsys: pytest.CaptureFixture[str]) -> None:
    direct = run(sys.executable, "-m", "hubs", "pi-tool", "--config", CONFIG, "--selftest")
    assert direct.returncode == 0, direct.stderr
    assert direct.stdout.startswith("self-test of hub pi-tool: PASS\n")
    for argv in (["hub", "pi-tool", "--selftest"], ["selftest", "pi-tool"]):
        code = hubctl([*argv, "--config", str(CONFIG)])
        assert (code, capsys.readouterr().out) == (0, direct.stdout), argv


def test_a_bad_option_is_one_line_naming_the_process(capsys: pytest.CaptureFixture[str]) -> None:
    hub = run(sys.executable, "-m", "hubs", "pi-tool", "--config", CONFIG, "--failure", "nr=2")
    assert (hub.returncode, hub.stderr) == (2, "hub pi-tool: --failure 'nr=2': the probability must be within 0..1\n")
    code = hubctl(["hub", "pi-tool", "--config", str(CONFIG), "--failure", "nr=2"])
    assert (code, capsys.readouterr().err) == (2, hub.stderr.replace("hub pi-tool:", "hubctl:"))


def test_an_invalid_station_file_is_reported_with_file_and_line(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "hubs.toml"
    config.write_text(CONFIG.read_text(encoding="utf-8") + "\n[station.extra]\n", encoding="utf-8")
    direct = run(sys.executable, "-m", "controller", "--config", config)
    assert direct.returncode == 2 and direct.stderr.startswith("controller: "), direct.stderr
    assert f"{config}:" in direct.stderr and "Traceback" not in direct.stderr
    code = hubctl(["controller", "--config", str(config)])
    assert (code, capsys.readouterr().err) == (2, "hubctl: " + direct.stderr.removeprefix("controller: "))


def test_a_missing_config_file_or_unknown_hub_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nowhere.toml"
    for argv, prog in (([sys.executable, "-m", "hubs", "pi-tool", "--config", str(missing)], "hub pi-tool"),
                       ([sys.executable, "-m", "controller", "--config", str(missing)], "controller")):
        result = run(*argv)
        assert (result.returncode, result.stderr) == (2, f"{prog}: cannot read {missing}: No such file or directory\n")
    unknown = run(sys.executable, "-m", "hubs", "pi-nowhere", "--config", CONFIG)
    assert unknown.returncode == 2 and "Traceback" not in unknown.stderr, unknown.stderr
    assert unknown.stderr.startswith(f"hub pi-nowhere: {CONFIG}: no hub named 'pi-nowhere' (hubs: pi-tool,")
    assert hubctl(["hub", "pi-tool", "--config", str(missing)]) == 2
    assert capsys.readouterr().err == f"hubctl: cannot read {missing}: No such file or directory\n"


def test_a_reader_that_goes_away_ends_hubctl_quietly(tmp_path: Path) -> None:
    """`hubctl ... | head`: the closed pipe ends hubctl with 141 (as SIGPIPE would), no traceback."""
    import os

    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run([sys.executable, "-m", "deploy.cli", "check"], cwd=ROOT, stdout=write_end,
                                stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert (result.returncode, result.stderr) == (141, "")
