"""The Modbus TCP remote-I/O coupler of the tool changer and its dock: the I/O map.

=========  ====  =============================================================
table      addr  signal
=========  ====  =============================================================
coil       0     tool changer *lock* valve solenoid
coil       1     tool changer *unlock* valve solenoid
discrete   0     piston in *locked* position
discrete   1     piston in *unlocked* position
discrete   2     air pressure OK (pressure switch)
discrete   3     tool present on the tool plate
discrete   4-5   tool code (bit 0, bit 1): n = the n-th of `TOOLS`, 0 none
discrete   8+    dock slot n+1 occupied (the home of the n-th of `TOOLS`)
=========  ====  =============================================================

Addresses are the drivers' defaults (`coil_base`, `di_base`); unit id 1. Shared by the
drivers (`hubs.drivers.rsp_modbus`, `hubs.drivers.dock_modbus`) and the simulator
(`hubs.sim.toolchanger_modbus`).
"""

from __future__ import annotations

DEVICE_ID = 1
TOOLS = ("nutrunner", "lift_tool", "filter_tool")  # tool code n+1, dock slot n+1
COIL_LOCK, COIL_UNLOCK = 0, 1
DI_LOCKED, DI_UNLOCKED, DI_PRESSURE, DI_PRESENT, DI_CODE0, DI_CODE1 = range(6)
CHANGER_INPUTS = 6
DI_DOCK = 8  # the dock's first slot, after the tool changer's inputs
