"""The operator's pages of a `hubctl up` run: each operator device that runs in mode real serves one,
and `up` prints where to open it, so that a person can run the station from a browser."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

from common.config.hubs_toml import StationConfig
from common.config.modes import DeviceMode, SecurityMode
from hubs.drivers.operator_page.address import needs_a_token, page_url
from hubs.drivers.operator_page.driver import OPERATOR_TYPE
from hubs.drivers.operator_page.params import OperatorPageParams
from hubs.factory import chosen_mode, resolve


@dataclass(frozen=True)
class OperatorPage:
    resource: str
    hub: str
    url: str
    needs_token: bool  # the page has tokens but none for the panel: the URL needs `?token=` added

    def line(self) -> str:
        hint = " (add ?token=TOKEN: one of the device's tokens in hubs.toml)" if self.needs_token else ""
        return f"operator's page ({self.resource} on hub {self.hub}): {self.url}{hint}"


def operator_pages(config: StationConfig, mode: DeviceMode | None, real: Collection[str]) -> list[OperatorPage]:
    """The operator devices this run serves a page for, in hubs.toml's order."""
    pages = []
    tls = config.security.mode == SecurityMode.TLS
    for hub in config.hubs.values():
        for resource, device in hub.devices.items():
            if device.type != OPERATOR_TYPE or chosen_mode(resource, device.type, device.mode, mode, real) \
                    != DeviceMode.REAL:
                continue
            params = resolve(device.type, DeviceMode.REAL, device.params).params
            if isinstance(params, OperatorPageParams):  # a plugin may serve the operator otherwise
                pages.append(OperatorPage(resource, hub.name, page_url(params, tls=tls), needs_a_token(params)))
    return pages
