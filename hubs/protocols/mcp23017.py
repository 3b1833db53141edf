"""The MCP23017 16-bit I2C port expander: its register map (IOCON.BANK = 0) and IOCON bits.

====  =======  ====  =======  ====  ========
addr  reg      addr  reg      addr  reg
====  =======  ====  =======  ====  ========
0x00  IODIRA   0x08  INTCONA  0x10  INTCAPA
0x01  IODIRB   0x09  INTCONB  0x11  INTCAPB
0x02  IPOLA    0x0A  IOCON    0x12  GPIOA
0x03  IPOLB    0x0B  IOCON    0x13  GPIOB
0x04  GPINTENA 0x0C  GPPUA    0x14  OLATA
0x05  GPINTENB 0x0D  GPPUB    0x15  OLATB
0x06  DEFVALA  0x0E  INTFA
0x07  DEFVALB  0x0F  INTFB
====  =======  ====  =======  ====  ========

IODIR bit 1 = input; GPIO reads pin levels; OLAT holds the output latches. Shared by
the driver (`hubs.drivers.nutrunner_mcp23017`) and the simulator (`hubs.sim.mcp23017`).
"""

from __future__ import annotations

IODIRA, IODIRB, IPOLA, IPOLB = 0x00, 0x01, 0x02, 0x03
GPINTENA, GPINTENB, DEFVALA, DEFVALB = 0x04, 0x05, 0x06, 0x07
INTCONA, INTCONB, IOCON, IOCON_ALT = 0x08, 0x09, 0x0A, 0x0B
GPPUA, GPPUB, INTFA, INTFB = 0x0C, 0x0D, 0x0E, 0x0F
INTCAPA, INTCAPB, GPIOA, GPIOB, OLATA, OLATB = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15
NREG = 0x16
IOCON_BANK, IOCON_MIRROR, IOCON_SEQOP = 0x80, 0x40, 0x20
DEFAULT_ADDRESS = 0x20
