"""The operator page's driver without a browser: its parameters in hubs.toml, the console's words for a
refused press, TLS with the station CA's certificate, the pushbutton's expander lost and back, the keys
and the access rule of the call for the supervisor."""

from __future__ import annotations

import asyncio
import http.client
import json
import ssl
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from common.config.acl import hub_grants
from common.config.hubs_toml import load_station
from common.config.security import identity_of
from common.resources.operator_confirm import confirm_refusal
from common.wire.keys import station_keys
from deploy.certs import init_ca, issue
from hubs.drivers.operator_page.button import OperatorButton
from hubs.drivers.operator_page.fake_expander import ButtonOnExpander
from hubs.drivers.operator_page.pushbutton import Pushbutton
from hubs.factory import device_problems
from tests.operator_page_support import ROOT, TOKEN, running_page

REPO_FILE = ROOT / "hubs.toml"


def operator_in_real_mode(tmp_path: Path, *extra: str, security: str = "") -> Path:
    text = REPO_FILE.read_text()
    device = '[hubs.human.devices.human]             # mode "real": the operator\'s page (docs/operator.md)\n' \
             'type = "operator"\nmode = "emulate"\n'
    assert device in text
    text = text.replace(device, device.replace('mode = "emulate"', 'mode = "real"') + "".join(f"{e}\n" for e in extra))
    if security:
        text = text.replace('mode = "insecure"', security)
    path = tmp_path / "hubs.toml"
    path.write_text(text)
    return path


def test_the_reference_operator_in_real_mode_is_a_valid_device(tmp_path: Path) -> None:
    config, _ = load_station(operator_in_real_mode(tmp_path))
    assert device_problems(config, hub="human") == []


@pytest.mark.parametrize(("extra", "key", "says"), [
    ('tokens = { watch = "short" }', "hubs.human.devices.human.tokens.watch", "at least 16 characters"),
    ("port = 70000", "hubs.human.devices.human.port", "<= 65535"),
    ('host = "no where"', "hubs.human.devices.human.host", "not an address to bind to"),
    ('button = { pin = "C9" }', "hubs.human.devices.human.button.pin", "A0..A7 or B0..B7"),
    ('bind = "0.0.0.0"', "hubs.human.devices.human.bind", "unknown parameter"),
])
def test_a_bad_parameter_is_named_with_file_line_and_key(tmp_path: Path, extra: str, key: str, says: str) -> None:
    path = operator_in_real_mode(tmp_path)
    text = path.read_text()
    # appended after the human device's keys (the file's last table), so that the duplicate wins nothing
    path.write_text(text.replace('port = 8080\n', '' if extra.startswith("port") else 'port = 8080\n')
                    .replace('host = "0.0.0.0"', '' if extra.startswith("host") else 'host = "0.0.0.0"')
                    + extra + "\n")
    config, _ = load_station(path)
    problems = device_problems(config, hub="human")
    assert [(p.key, p.file) for p in problems] == [(key, str(path))]
    assert says in problems[0].message
    line = path.read_text().splitlines().index(extra) + 1
    assert problems[0].line == line


def test_the_page_refuses_in_the_console_s_words() -> None:
    """The refusals come from common/resources/operator_confirm.py, which controller/requests.py uses too."""
    _, model = load_station(REPO_FILE)
    button = OperatorButton(model, "human")
    assert button.refusal() == "human has no instruction to confirm"
    button.command("lift_frame")
    assert button.refusal() == confirm_refusal(model, "human", {**button.values})
    assert button.refusal() == ("human cannot confirm lift_frame yet: "
                                "engine.frame_e == lifted && ur.pos_m == above_engine")
    assert button.press() is not None and not button.done
    button.observe({"engine.frame_e": "lifted", "ur.pos_m": "above_engine", "lift.pos_m": "down"})
    assert button.press() is None and button.done
    assert button.refusal() == "human has already confirmed lift_frame"
    button.command("none")
    assert not button.done  # released, as the model's release_button expects


def test_in_tls_mode_the_page_is_served_with_the_station_ca_s_certificate(tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    path = operator_in_real_mode(tmp_path, security=f'mode = "tls"\ncerts = "{certs}"')
    config, _ = load_station(path)
    init_ca(certs, config.station.name)
    issue(certs, identity_of(config, "human"), ["localhost"])
    with running_page(config_path=path) as page:
        assert page.url.startswith("https://127.0.0.1:")
        trusting = ssl.create_default_context(cafile=str(certs / "ca.crt"))
        with urllib.request.urlopen(page.url + "api/view", context=trusting, timeout=10) as response:
            assert json.loads(response.read())["resource"] == "human"
        with pytest.raises((urllib.error.URLError, http.client.HTTPException, ConnectionError)):  # no plain HTTP
            urllib.request.urlopen(page.url.replace("https", "http") + "api/view", timeout=10)
        with pytest.raises(urllib.error.URLError, match="CERTIFICATE_VERIFY_FAILED"):
            urllib.request.urlopen(page.url + "api/view", context=ssl.create_default_context(), timeout=10)


def test_a_pushbutton_whose_expander_is_lost_counts_no_press_and_works_again_when_it_returns() -> None:
    async def scenario() -> None:
        expander = ButtonOnExpander(address=0x22, pin=(0, 5))
        presses: list[float] = []
        button = Pushbutton(expander.open, 0x22, (0, 5), poll_s=0.005, on_press=lambda: presses.append(time.time()))
        button.start()
        try:
            await until(lambda: button.answering)
            expander.present = False
            await until(lambda: "0x22" in button.last_error)
            expander.press()
            await asyncio.sleep(0.05)
            assert presses == []
            expander.present = True
            expander.chip.power_on_reset()  # it lost its configuration: the pull-up is set again
            await until(lambda: len(presses) == 1)
            expander.press(False)
            await until(lambda: not button.pressed)
            expander.press()
            await until(lambda: len(presses) == 2)  # each press once, however long it is held
            await asyncio.sleep(0.05)
            assert len(presses) == 2
        finally:
            await button.stop()

    asyncio.run(scenario())


async def until(condition: object, timeout: float = 20.0) -> None:
    assert callable(condition)
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "never happened"
        await asyncio.sleep(0.005)


def test_the_call_for_the_supervisor_is_a_token_only_its_hub_may_hold() -> None:
    keys = station_keys("engine_assembly")
    key = keys.call("human", "human")
    assert key == "engine_assembly/hub/human/call/human"
    assert keys.call_of(key) == ("human", "human")
    assert keys.call_of(keys.alive("human")) is None
    grants = hub_grants(keys, "human", ["human"], [])
    tokens = [grant.keys for grant in grants if "liveliness_token" in grant.messages]
    assert tokens == [(keys.alive("human"), key)]


def post_raw(url: str, data: bytes, token: str | None = None) -> tuple[int, dict[str, object]]:
    request = urllib.request.Request(url, data=data, method="POST", headers={"Content-Type": "application/json"})
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


def test_bad_requests_to_the_endpoints_get_a_clear_error_and_change_nothing() -> None:
    with running_page({"tokens": {"watch": TOKEN}}) as page:
        nothing_standing = page.run(page.page.view)
        # A confirm while no instruction stands: refused in the console's words.
        assert page.post("api/confirm", token=TOKEN) == (409, {
            "accepted": False, "reason": "human has no instruction to confirm", "refusal": "cannot_confirm"})
        assert page.run(page.page.view) == nothing_standing
        page.write(instr_c="mount_filter1")  # a task without a condition: a press would be taken
        standing = page.run(page.page.view)
        assert standing.can_confirm
        wrong, no_token = "wrong-token-0000000000", "wrong or missing device token"
        bad: list[tuple[str, bytes, str | None, int, str]] = [
            ("api/confirm", b'{"task": "mount_filter1"}', wrong, 403, no_token),
            ("api/confirm", b"", None, 403, no_token),
            ("api/call-supervisor", b"", wrong, 403, no_token),
            ("api/confirm", b'{"task": "no_such_task"}', TOKEN, 400, "unknown task 'no_such_task'"),
            ("api/confirm", b'{"task": "mount_filter2"}', TOKEN, 409, "is not the instruction standing"),
            ("api/confirm", b"not json", TOKEN, 400, "the body is not JSON"),
            ("api/confirm", b'["mount_filter1"]', TOKEN, 400, 'expected {"task": "TASK"} or no body'),
            ("api/confirm", b'{"task": 3}', TOKEN, 400, 'expected {"task": "TASK"} or no body'),
        ]
        for path, body, token, status, says in bad:
            answer_status, answer = post_raw(page.url + path, body, token)
            assert (answer_status, answer["accepted"]) == (status, False), (path, body, answer)
            assert says in str(answer["reason"]), (path, body, answer)
            assert page.run(page.page.view) == standing, (path, body)  # nothing changed: button, call, view
        assert not page.done() and not page.page.supervisor_called
        # The right token still presses, once: a second press changes nothing more.
        assert post_raw(page.url + "api/confirm", b'{"task": "mount_filter1"}', TOKEN)[0] == 200
        confirmed = page.run(page.page.view)
        status, answer = post_raw(page.url + "api/confirm", b"", TOKEN)
        assert (status, answer["reason"]) == (409, "human has already confirmed mount_filter1")
        assert page.run(page.page.view) == confirmed
