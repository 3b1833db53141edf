"""Where a browser opens the operator's page, from the device's parameters: what `hubctl up` prints.

A page bound to every interface (`0.0.0.0`, `::`) is reached on loopback from the hub's own machine; a
page with tokens needs one in its address, the panel's when hubs.toml names a device `panel`."""

from __future__ import annotations

import ipaddress
from urllib.parse import quote

from .params import OperatorPageParams

PANEL_DEVICE = "panel"  # the token the page itself presents (docs/operator.md)


def page_url(params: OperatorPageParams, *, tls: bool) -> str:
    """The page's address for a browser on the hub's machine, with the panel's token if it has one."""
    try:
        address: ipaddress.IPv4Address | ipaddress.IPv6Address | None = ipaddress.ip_address(params.host)
    except ValueError:
        address = None  # a host name
    if address is not None and address.is_unspecified:
        address = ipaddress.ip_address("127.0.0.1" if address.version == 4 else "::1")
    host = params.host if address is None else f"[{address}]" if address.version == 6 else str(address)
    url = f"{'https' if tls else 'http'}://{host}:{params.port}/"
    token = params.tokens.get(PANEL_DEVICE)
    return f"{url}?token={quote(token, safe='')}" if token else url


def needs_a_token(params: OperatorPageParams) -> bool:
    """Every press needs a token, and the printed address carries none: the person must add theirs."""
    return bool(params.tokens) and PANEL_DEVICE not in params.tokens
