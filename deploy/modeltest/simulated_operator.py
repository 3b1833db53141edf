"""A simulated operator for `hubctl test` against the operator's hub in mode real (`--simulated-operator`).

In mode real the operator's device is the operator's page (hubs/drivers/operator_page): `done_m` goes
true only when someone presses Confirm. To hold that driver to the model, this plays the person: it
follows what the page shows (`GET /api/view`) and presses whenever the page says a press would be
taken, through the same HTTP endpoint a smartwatch uses (`POST /api/confirm` with the device's token).
The model-based test then expects `done_m := true` within its deadline exactly where the model's
confirmation effect is enabled, and checks the page never confirms anything else."""

from __future__ import annotations

import json
import ssl
import threading
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

from common.config.hubs_toml import StationConfig
from common.config.modes import SecurityMode
from common.config.security import cert_dir
from hubs.drivers.operator_page.address import page_url
from hubs.drivers.operator_page.driver import OPERATOR_TYPE
from hubs.drivers.operator_page.params import OperatorPageParams
from hubs.drivers.params import ParamError, convert_params
from hubs.factory import EMULATION_PARAMS

POLL_S = 0.05  # well inside any deadline of the test (seconds)
REQUEST_TIMEOUT_S = 5.0


class NoOperatorPage(Exception):
    """The resource has no operator's page to press on; the message says why."""


@dataclass(frozen=True)
class PageAccess:
    """How to reach one operator's page: its address, the token presented, how TLS is verified."""

    resource: str
    url: str  # ends with "/"
    token: str  # "" when the page takes presses without one
    device: str  # the token's device name in hubs.toml, for the report
    tls: ssl.SSLContext | None = field(default=None, compare=False)


def page_access(config: StationConfig, resource: str, device: str | None,
                certs: str | None = None) -> PageAccess:
    """The page of operator `resource` as hubs.toml describes it, pressing with the token of `device`
    (None: the page's only token, or none when it has no tokens). Raises NoOperatorPage."""
    hub = config.resources.get(resource)
    if hub is None or hub.devices[resource].type != OPERATOR_TYPE:
        raise NoOperatorPage(f"{resource} is no operator device of {config.path}")
    raw = {k: v for k, v in hub.devices[resource].params.items() if k not in EMULATION_PARAMS}
    try:
        params = convert_params(OperatorPageParams, raw)
    except ParamError as exc:
        raise NoOperatorPage(f"{resource}: the operator page's parameters: {exc}") from exc
    if device:
        if device not in params.tokens:
            raise NoOperatorPage(f"{resource}: no token for device {device!r} in {config.path} (its devices: "
                                 f"{', '.join(params.tokens) or 'none: the page needs no token'})")
        token = params.tokens[device]
    elif len(params.tokens) > 1:
        raise NoOperatorPage(f"{resource}: the page has tokens for {', '.join(params.tokens)}: name the device "
                             f"whose token to press with (--simulated-operator DEVICE)")
    else:
        device, token = next(iter(params.tokens.items()), ("page", ""))
    tls = config.security.mode == SecurityMode.TLS
    context = None
    if tls:
        # Trust the station CA, as the operator's tablet does; the page's address is whatever hubs.toml
        # binds (127.0.0.1 for 0.0.0.0), which its hub's certificate need not name.
        context = ssl.create_default_context(cafile=str(Path(cert_dir(config, certs)) / "ca.crt"))
        context.check_hostname = False
    return PageAccess(resource, page_url(params, tls=tls).split("?", 1)[0], token, device, context)


class SimulatedOperator:
    """Presses Confirm on one operator's page whenever the page says it may, in a thread of its own."""

    def __init__(self, access: PageAccess, poll_s: float = POLL_S) -> None:
        self.access = access
        self.poll_s = poll_s
        self.presses = 0  # presses the page took
        self.refused: list[str] = []  # the reasons of presses it refused (the view changed meanwhile)
        self.error: str | None = None  # the last failure to reach the page, None once it answers again
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"simulated-operator-{access.resource}", daemon=True)

    def view(self) -> dict[str, object]:
        with urllib.request.urlopen(self.access.url + "api/view", timeout=REQUEST_TIMEOUT_S,
                                    context=self.access.tls) as response:
            answer = json.loads(response.read())
        if not isinstance(answer, dict):
            raise ValueError(f"{self.access.url}api/view answered {answer!r}")
        return answer

    def wait_for_page(self, timeout: float) -> None:
        """Until the page answers; raises NoOperatorPage naming the address after `timeout` seconds."""
        if not self._answers(timeout):
            raise NoOperatorPage(f"{self.access.resource}: no operator's page answers at {self.access.url} "
                                 f"({self.error}): is the device in mode real (hubs.toml, or `hubctl hub --real "
                                 f"{self.access.resource}`)?")

    def _answers(self, timeout: float) -> bool:
        waited = 0.0
        while True:
            try:
                self.view()
                self.error = None
                return True
            except (OSError, ValueError) as exc:
                self.error = str(exc)
            if waited >= timeout:
                return False
            self._stop.wait(0.2)
            waited += 0.2

    def press(self, task: str) -> None:
        request = urllib.request.Request(self.access.url + "api/confirm", method="POST",
                                         data=json.dumps({"task": task}).encode(),
                                         headers={"Content-Type": "application/json"})
        if self.access.token:
            request.add_header("Authorization", f"Bearer {self.access.token}")
        try:
            with urllib.request.urlopen(request, timeout=REQUEST_TIMEOUT_S, context=self.access.tls):
                self.presses += 1
        except urllib.error.HTTPError as refused:
            if refused.code == 403:  # a wrong token stays wrong: say it rather than press on
                raise NoOperatorPage(f"{self.access.resource}: the page refused the token of "
                                     f"{self.access.device!r}") from refused
            self.refused.append(json.loads(refused.read() or b"{}").get("reason", str(refused)))

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            try:
                view = self.view()
                if view.get("can_confirm") and not view.get("done"):
                    self.press(str(view["task"]))
                self.error = None
            except NoOperatorPage as exc:
                self.error = str(exc)
                return
            except (OSError, ValueError) as exc:
                self.error = str(exc)

    def start(self) -> SimulatedOperator:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(REQUEST_TIMEOUT_S + 1)

    def describe(self) -> str:
        refused = f", {len(self.refused)} refused (the page changed meanwhile)" if self.refused else ""
        failed = f"; last error: {self.error}" if self.error else ""
        return (f"simulated operator of {self.access.resource} ({self.access.url}, token of {self.access.device}): "
                f"{self.presses} presses taken{refused}{failed}")
