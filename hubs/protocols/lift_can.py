"""The lift's CAN frame map (11-bit ids, CANopen-style COB-IDs around node id N; little-endian).

===========  ===========  ===  ====================================================
COB-ID       direction    DLC  payload
===========  ===========  ===  ====================================================
0x200 + N    hub → lift   2    command (STOP, UP, DOWN), sequence counter (mod 256)
0x180 + N    lift → hub   6    position mm (uint16), flags, fault code, echo of the
             every 20 ms        last command and its sequence (`STATUS_FORMAT`)
0x700 + N    lift → hub   1    NMT heartbeat: BOOT, OPERATIONAL, PREOPERATIONAL
             every 100 ms
===========  ===========  ===  ====================================================

The lift stops by itself when no command frame arrived for `COMMAND_TIMEOUT_S`.
Shared by the driver (`hubs.drivers.lift_can`) and the simulator (`hubs.sim.lift_can`).
"""

from __future__ import annotations

COB_COMMAND, COB_STATUS, COB_HEARTBEAT = 0x200, 0x180, 0x700
CMD_STOP, CMD_UP, CMD_DOWN = 0, 1, 2
NMT_BOOT, NMT_OPERATIONAL, NMT_PREOP = 0x00, 0x05, 0x7F
FLAG_UPPER, FLAG_LOWER, FLAG_MOVING_UP, FLAG_MOVING_DOWN, FLAG_FAULT = 0x01, 0x02, 0x04, 0x08, 0x80
STATUS_FORMAT = "<HBBBB"  # position, flags, fault code, echo command, echo sequence
COMMAND_TIMEOUT_S = 0.5
DEFAULT_NODE = 0x10
