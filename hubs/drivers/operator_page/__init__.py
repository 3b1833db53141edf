"""The operator's page: the driver of device type `operator` in mode `real` (docs/operator.md).

driver.py the Driver; button.py the model's button; view.py what the page shows; server.py the HTTP
side (aiohttp); tokens.py the devices' tokens; pushbutton.py a GPIO button on an MCP23017 and
fake_expander.py its simulator; params.py the hubs.toml parameters; static/ the page itself."""

from __future__ import annotations

from hubs.drivers.registry import DriverPlugin

from .driver import build
from .params import OperatorPageParams

PLUGIN = DriverPlugin(OperatorPageParams, build)
