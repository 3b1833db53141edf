"""What goes through the pipe from the controller's RecordingWriter (writer.py) to its writer process.

A message is a header (its type, the payload's length) and a payload:

* RECORDS: a MessagePack array of records `[t, kind, key, data]`, `data` the kind's struct as stored.
  The controller thread appends each record to the array in place (`RecordBuffer`): one msgspec call, no
  Python object kept for later, so no garbage collections that records waiting for the disk used to cause.
* META: a MessagePack map of RunMeta fields to set.
* CLOSE: the same, then the run's end: the writer process writes it, completes the file and exits.

A record of kind `ingested` (never stored as such) carries an ingested batch as the controller took it:
`[changed values, hub states]`, every sample's hub state. The writer process decides what of it a `states`
row keeps (schema.StatesFilter): the controller thread runs no Python per state for the recording.
"""

from __future__ import annotations

import struct
from typing import Any

import msgspec

from common.model import Value
from controller.recording.schema import HubState

HEADER = struct.Struct(">BI")  # message type, payload length
RECORDS, META, CLOSE = 1, 2, 3
INGESTED = "ingested"  # the kind of a raw ingested batch, on the wire only
_ARRAY32 = 0xDD  # MessagePack: an array with a 32-bit count
_RESERVED = HEADER.size + 5  # the message header, then the array's header

WireRecord = tuple[float, str, str, msgspec.Raw]


class RecordBuffer:
    """Records appended in place, taken as one RECORDS message."""

    def __init__(self) -> None:
        self._encode_into = msgspec.msgpack.Encoder().encode_into
        self.count = 0
        self._buffer = bytearray(_RESERVED)

    def __len__(self) -> int:
        return len(self._buffer)

    def append(self, record: tuple[float, str, str, Any]) -> None:
        """Raises TypeError (or ValueError, OverflowError) for what cannot be encoded, leaving the buffer as it was."""
        buffer = self._buffer
        size = len(buffer)
        try:
            self._encode_into(record, buffer, -1)
        except (TypeError, ValueError, OverflowError):
            del buffer[size:]  # msgspec leaves what it wrote before it failed
            raise
        self.count += 1

    def take(self) -> bytearray:
        """The message of the records appended since the last take (the buffer starts afresh)."""
        message, self._buffer = self._buffer, bytearray(_RESERVED)
        HEADER.pack_into(message, 0, RECORDS, len(message) - HEADER.size)
        message[HEADER.size] = _ARRAY32
        struct.pack_into(">I", message, HEADER.size + 1, self.count)
        self.count = 0
        return message


def message(kind: int, fields: dict[str, Any]) -> bytes:
    """A META or CLOSE message."""
    payload = msgspec.msgpack.encode(fields)
    return HEADER.pack(kind, len(payload)) + payload


_RECORDS = msgspec.msgpack.Decoder(list[WireRecord])
_INGESTED = msgspec.msgpack.Decoder(tuple[dict[str, Value], list[HubState]])
_FIELDS = msgspec.msgpack.Decoder(dict[str, Any])


def decode_records(payload: bytes) -> list[WireRecord]:
    """A RECORDS payload's records, each `data` still encoded (a view of `payload`)."""
    return _RECORDS.decode(payload)


def decode_ingested(data: msgspec.Raw) -> tuple[dict[str, Value], list[HubState]]:
    return _INGESTED.decode(data)


def decode_fields(payload: bytes) -> dict[str, Any]:
    return _FIELDS.decode(payload)
