"""EM4100 badge readers on a serial line: one ASCII frame per scan, 9600 8N1.

    STX 0x02 | 10 hex chars: the 5 tag bytes | 2 hex chars: XOR of the 5 bytes | CR LF | ETX 0x03

Shared by the driver (`hubs.drivers.rfid_serial`, which parses frames) and the
simulator (`hubs.sim.rfid_serial`, which writes them).
"""

from __future__ import annotations

STX, ETX = 0x02, 0x03
TAG_CHARS = 10
FRAME_BODY = TAG_CHARS + 2 + 2  # tag, checksum, CR LF: what lies between STX and ETX
BAUDRATE = 9600


def checksum(tag_bytes: bytes) -> int:
    """XOR of the tag's bytes."""
    value = 0
    for byte in tag_bytes:
        value ^= byte
    return value
