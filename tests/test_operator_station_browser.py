"""The whole reference station run by a person in a browser: `hubctl up --real human` (every hub and the
controller as processes over Zenoh, every device emulated but the operator, whose hub serves the operator's
page), a headless Chromium playing the operator and another showing the supervisors' overview.

The operator reads each instruction, checks its text against the station's instruction table (the step the
page shows names the table's entry), clicks Confirm, and the station finishes: `up` exits 0 with every
operation done. A screenshot of each distinct page state is written to the test's directory, and one taken
while an instruction stood is checked to be drawn (many colours, the instruction's text displayed then). The
overview, opened beside, is screenshot while the station runs and shows every operation of the model."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from PIL import Image
from selenium.webdriver.remote.webdriver import WebDriver

from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import free_port
from common.stations.engine_assembly_instructions import INSTRUCTIONS
from tests.browser import chromium
from tests.fault_station.harness import ROOT, write_config
from tests.test_overview_browser import overview, rows

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SPEED = 3.0  # the emulated devices' delays / 3: the operator's waits are the browser's own
RUN_LIMIT_S = 420.0  # generous: the machine is shared; the run takes about a minute
POLL_S = 0.1
LANGUAGE = "en"  # the reference hubs.toml names none: the table's first
RENDERED_COLOURS = 64  # a blank or unstyled page has a handful; text on the picture, hundreds

# What the page shows, read in one go so that no update falls between two reads.
PAGE_STATE = """const $ = (id) => document.getElementById(id);
const visible = (e) => !!e && !e.hidden && e.offsetWidth > 0 && e.offsetHeight > 0;
return {instruction: $('instruction').textContent, shown: visible($('instruction')), step: $('step').textContent,
        enabled: !$('confirm').disabled, button: $('confirm').textContent, reason: $('reason').textContent,
        operator: $('operator').textContent, connected: $('connection').hidden,
        picture: visible($('picture')) && $('picture').naturalWidth > 0};"""


@dataclass(frozen=True)
class PageState:
    instruction: str
    shown: bool
    step: str
    enabled: bool
    button: str
    reason: str
    operator: str
    connected: bool
    picture: bool

    @property
    def distinct(self) -> tuple[str, str, bool, str, str]:
        """What makes a state another one for the screenshots (the robot's pose changes too often)."""
        return self.instruction, self.step, self.enabled, self.button, self.reason

    def step_number(self) -> int | None:
        found = re.fullmatch(r"Step (\d+) of (\d+)", self.step)
        if found is None:
            return None
        assert int(found[2]) == len(INSTRUCTIONS.steps), self.step
        return int(found[1])


@dataclass(frozen=True)
class Screenshot:
    path: Path
    state: PageState


@dataclass
class Up:
    """`hubctl up` as a process, its output in a file."""

    process: subprocess.Popen[bytes]
    output: Path

    def text(self) -> str:
        return self.output.read_text(errors="replace") if self.output.exists() else ""

    def line(self, pattern: str, timeout: float) -> re.Match[str]:
        deadline = time.monotonic() + timeout
        while True:
            found = re.search(pattern, self.text(), re.MULTILINE)
            if found is not None:
                return found
            assert self.process.poll() is None, f"hubctl up exited with {self.process.returncode}:\n{self.text()}"
            assert time.monotonic() < deadline, f"hubctl up never printed /{pattern}/:\n{self.text()}"
            time.sleep(POLL_S)


@contextlib.contextmanager
def hubctl_up(config: Path, directory: Path) -> Iterator[Up]:
    """`hubctl up --real human` in `directory` (its var/up/ there); Ctrl-C'd if it is still running at the end."""
    output = directory / "up.out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    argv = [sys.executable, "-c", "from deploy.cli import run; run()", "up",
            "--config", str(config), "--real", "human", "--speed", str(SPEED), "--time-limit", str(RUN_LIMIT_S)]
    with output.open("wb") as handle:
        process = subprocess.Popen(argv, cwd=directory, env=env, stdout=handle, stderr=subprocess.STDOUT,
                                   start_new_session=True)
    up = Up(process, output)
    try:
        yield up
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)  # up stops its processes, as on Ctrl-C
            try:
                process.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(10)
        print(f"\n----- hubctl up ({output}) -----\n{up.text()[-6000:]}")


def page_state(browser: WebDriver) -> PageState:
    return PageState(**browser.execute_script(PAGE_STATE))


def colours(png: Path) -> int:
    with Image.open(png) as image:
        found = image.convert("RGB").getcolors(maxcolors=1 << 16)
    return len(found) if found is not None else 1 << 16


def test_a_person_runs_the_reference_station_from_the_operator_s_page(tmp_path: Path) -> None:
    page_port = free_port()
    config = write_config(tmp_path, ROOT / "hubs.toml", prefix="opstation",
                          replace=[("port = 8080", f"port = {page_port}"),
                                   ('host = "0.0.0.0"', 'host = "127.0.0.1"')])  # only this machine's browser
    model = load_station(config)[1]
    shots = tmp_path / "screenshots"
    shots.mkdir()
    with hubctl_up(config, tmp_path) as up, chromium() as operator, chromium() as supervisor:
        url = up.line(r"operator's page \(human on hub human\): (\S+)$", 120)[1]
        assert url == f"http://127.0.0.1:{page_port}/"
        controller_port = int(up.line(r"console: hubctl console .* --connect tcp/127\.0\.0\.1:(\d+)", 10)[1])
        with overview(config, controller_port, tmp_path) as served:
            supervisor.get(served.url)
            operator.get(url)
            screenshots: list[Screenshot] = []
            confirmed: dict[int, str] = {}  # step -> the instruction confirmed there
            overview_shot: Path | None = None
            seen: set[tuple[str, str, bool, str, str]] = set()
            deadline = time.monotonic() + RUN_LIMIT_S
            while up.process.poll() is None:
                assert time.monotonic() < deadline, f"the station did not finish:\n{up.text()[-3000:]}"
                state = page_state(operator)
                if state.connected and state.distinct not in seen:
                    seen.add(state.distinct)
                    path = shots / f"operator-{len(screenshots):02d}.png"
                    operator.save_screenshot(str(path))
                    screenshots.append(Screenshot(path, state))
                step = state.step_number()
                # The operator reads once the picture is in too (it loads after the text).
                if state.enabled and step is not None and step not in confirmed and state.picture:
                    # The instruction the operator reads is the table's for the step the page says.
                    assert state.instruction == INSTRUCTIONS.steps[step - 1].text_in(LANGUAGE), state
                    assert state.shown, state
                    operator.find_element("id", "confirm").click()
                    confirmed[step] = state.instruction
                if confirmed and overview_shot is None and len(rows(supervisor, "#operations")) == \
                        len(model.operations):
                    overview_shot = shots / "overview.png"
                    supervisor.save_screenshot(str(overview_shot))
                    shown = {r["name"]: r["state"] for r in rows(supervisor, "#operations")}
                    assert set(shown) == {op.name for op in model.operations}
                    assert "finished" in shown.values(), shown
                time.sleep(POLL_S)
    output = up.text()
    assert up.process.returncode == 0, output[-3000:]
    assert f"finished: {len(model.operations)}/{len(model.operations)} operations" in output
    # Every instruction of the table stood once and was confirmed from the page, in the table's words.
    assert sorted(confirmed) == list(range(1, len(INSTRUCTIONS.steps) + 1)), confirmed
    # One screenshot per distinct state, and the ones taken while an instruction stood are drawn.
    assert len(screenshots) == len(seen) > len(INSTRUCTIONS.steps)
    standing = [shot for shot in screenshots if shot.state.step_number() is not None and shot.state.shown]
    assert standing, [shot.state for shot in screenshots]
    assert colours(standing[0].path) > RENDERED_COLOURS, standing[0]
    assert overview_shot is not None, "the overview never showed every operation"
    assert colours(overview_shot) > RENDERED_COLOURS
