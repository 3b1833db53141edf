"""The operator's page in a real headless Chromium (tests/browser.py), the driver in this process:
who works here, the instruction following the commands, the Confirm button and its reasons, the
device endpoint with its token, the GPIO pushbutton through the fake MCP23017."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from selenium.webdriver.chrome.webdriver import WebDriver
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from hubs.drivers.operator_page.fake_expander import ButtonOnExpander
from hubs.drivers.rfid_serial import RfidSerial
from hubs.sim.rfid_serial import frame
from tests.browser import chromium
from tests.operator_page_support import TOKEN, RunningPage, running_page

WAIT_S = 20.0  # the machine is loaded: generous, never a timing the test asserts


@pytest.fixture(scope="module")
def browser() -> Iterator[WebDriver]:
    with chromium() as driver:
        yield driver


def text_of(browser: WebDriver, element: str) -> str:
    return str(browser.find_element(By.ID, element).text)


def wait_until(browser: WebDriver, holds: Callable[[WebDriver], object], what: str) -> None:
    WebDriverWait(browser, WAIT_S, poll_frequency=0.05).until(holds, message=f"the page never showed {what}")


def shows(element: str, text: str) -> Callable[[WebDriver], bool]:
    return lambda browser: text in text_of(browser, element)


def confirm_enabled(browser: WebDriver) -> bool:
    return bool(browser.find_element(By.ID, "confirm").is_enabled())


def wait_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"never: {what}"
        time.sleep(0.02)


def frame_ready(page: RunningPage) -> None:
    """What the hub would have seen when the frame sits on the engine: lift_frame may be confirmed."""
    page.observe({"engine.frame_e": "lifted", "ur.pos_m": "above_engine", "lift.pos_m": "down"})


def test_no_operator_then_the_verified_name_after_a_badge(browser: WebDriver) -> None:
    reader = RfidSerial("rfid", port="/dev/null", operators={"0A1B2C3D4E": "Anna Berg"})
    with running_page() as page:
        browser.get(page.url)
        wait_until(browser, shows("operator", "No operator verified"), "no operator verified")
        assert browser.find_element(By.ID, "operator").get_attribute("data-verified") == "false"
        page.run(lambda: reader.feed(frame("0A1B2C3D4E")))  # the badge at the reader of this hub
        page.observe({"rfid.verified_m": True})  # the reader's state, as the hub hears it on the bus
        wait_until(browser, shows("operator", "Welcome, Anna Berg"), "the operator's name")
        assert browser.find_element(By.ID, "operator").get_attribute("data-verified") == "true"


def test_the_instruction_and_its_step_follow_the_commands(browser: WebDriver) -> None:
    with running_page() as page:
        browser.get(page.url)
        wait_until(browser, shows("instruction", "No instruction"), "no instruction")
        page.write(instr_c="place_bolts")
        wait_until(browser, shows("instruction", "Place the 24 frame bolts"), "the bolts' instruction")
        assert text_of(browser, "step") == "Step 2 of 8"
        picture = browser.find_element(By.ID, "picture")
        wait_until(browser, lambda b: picture.get_attribute("naturalWidth") not in (None, "0"), "the picture")
        page.write(instr_c="mount_filter3")
        wait_until(browser, shows("instruction", "Mount oil filter 3"), "the filter's instruction")
        assert text_of(browser, "step") == "Step 5 of 8"
        page.observe({"ur.pos_m": "unknown"})
        wait_until(browser, shows("robot", "Robot: moving"), "the robot moving")
        page.observe({"ur.pos_m": "at_bolt3"})
        wait_until(browser, shows("robot", "waits for you"), "the robot waiting for the operator")


def test_confirm_is_disabled_with_the_reason_then_a_click_confirms_and_the_release_follows(
        browser: WebDriver) -> None:
    with running_page() as page:
        browser.get(page.url)
        page.write(instr_c="lift_frame")
        wait_until(browser, shows("reason", "human cannot confirm lift_frame yet: engine.frame_e == lifted"),
                   "why Confirm is disabled")
        assert not confirm_enabled(browser)
        browser.find_element(By.ID, "confirm").click()  # a disabled button: nothing happens
        assert not page.done()
        frame_ready(page)
        wait_until(browser, confirm_enabled, "Confirm enabled")
        assert text_of(browser, "reason") == ""
        browser.find_element(By.ID, "confirm").click()
        wait_for(page.done, "done_m set by the click")
        wait_until(browser, shows("reason", "human has already confirmed lift_frame"), "the confirmation")
        page.write(instr_c="none")  # the controller withdraws the instruction: the button is released
        wait_for(lambda: not page.done(), "done_m released")
        wait_until(browser, shows("reason", "human has no instruction to confirm"), "no instruction")


def test_the_device_endpoint_takes_the_right_token_and_refuses_a_wrong_one(browser: WebDriver) -> None:
    with running_page({"tokens": {"watch": TOKEN}}) as page:
        browser.get(page.url)
        page.write(instr_c="mount_filter1")
        wait_until(browser, confirm_enabled, "Confirm enabled")
        status, answer = page.post("api/confirm", token="wrong-token-0000000000")
        assert (status, answer["accepted"]) == (403, False)
        status, _ = page.post("api/confirm")  # no token at all
        assert status == 403
        assert not page.done()
        status, answer = page.post("api/confirm", {"task": "mount_filter2"}, token=TOKEN)
        assert (status, answer["refusal"]) == (409, "not_standing")
        status, answer = page.post("api/confirm", {"task": "no_such_task"}, token=TOKEN)
        assert (status, answer["refusal"]) == (400, "unknown_task")
        assert not page.done()
        browser.find_element(By.ID, "confirm").click()  # the page opened without ?token=: refused too
        wait_until(browser, shows("message", "wrong or missing device token"), "the refusal of the page")
        assert not page.done()
        status, answer = page.post("api/confirm", {"task": "mount_filter1"}, token=TOKEN)
        assert (status, answer["accepted"]) == (200, True)
        assert page.done()
        wait_until(browser, shows("reason", "human has already confirmed mount_filter1"), "the confirmation")
        page.write(instr_c="none")
        status, answer = page.post("api/confirm", token=TOKEN)
        assert (status, answer["reason"]) == (409, "human has no instruction to confirm")
        assert not page.done()


def test_the_page_with_its_token_in_the_address_confirms(browser: WebDriver) -> None:
    with running_page({"tokens": {"panel": TOKEN}}) as page:
        browser.get(f"{page.url}?token={TOKEN}")
        page.write(instr_c="mount_oil_pipes")
        wait_until(browser, confirm_enabled, "Confirm enabled")
        browser.find_element(By.ID, "confirm").click()
        wait_for(page.done, "done_m set by the click")


def test_the_gpio_pushbutton_confirms_through_the_mcp23017(browser: WebDriver) -> None:
    expander = ButtonOnExpander(address=0x21, pin=(1, 3))
    with running_page({"button": {"bus": 1, "address": 0x21, "pin": "B3"}}, expander=expander) as page:
        browser.get(page.url)
        page.write(instr_c="lift_frame")
        wait_until(browser, shows("reason", "cannot confirm lift_frame yet"), "why Confirm is disabled")
        expander.press()  # pressed while the condition does not hold: refused, nothing changes
        wait_for(lambda: page.page.pushbutton is not None and page.page.pushbutton.presses == 1, "the press read")
        expander.press(False)
        # A hand lets go for longer than a poll; on a loaded machine the poll may come late, and a release it never
        # saw would make the next press part of this one (held down is one press).
        wait_for(lambda: page.page.pushbutton is not None and not page.page.pushbutton.pressed, "the release read")
        assert not page.done()
        frame_ready(page)
        wait_until(browser, confirm_enabled, "Confirm enabled")
        expander.press()
        wait_for(page.done, "done_m set by the pushbutton")
        wait_until(browser, shows("reason", "human has already confirmed lift_frame"), "the confirmation")
        expander.press(False)
        page.write(instr_c="none")
        wait_for(lambda: not page.done(), "done_m released")
