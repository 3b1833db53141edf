"""The largest MessagePack encoding a msgspec struct type can have, from its fields' types.

A payload longer than that cannot be a valid message of the type, so a receiver drops it
before decoding anything (issue 12: a 10 MB payload on a command key cost a hub 177 ms of
its loop and 76 MB of memory). Every field must be bounded: bools, None, floats, ints
(9 bytes at most), literals and enums, strings with a `max_length`, nested structs of
the same kind, and unions of these. An unbounded field (a plain `str`, a list) is a
`TypeError`: such a type has no size limit to check.
"""

from __future__ import annotations

import functools
from typing import Any

import msgspec
import msgspec.inspect as mi

MAX_INT_BYTES = 9  # int64 / uint64 and float64: one type byte and 8 data bytes
UTF8_MAX_BYTES_PER_CHAR = 4


def _int_bytes(value: int) -> int:
    if -32 <= value <= 127:
        return 1  # fixint
    for limit, size in ((0xFF, 2), (0xFFFF, 3), (0xFFFF_FFFF, 5)):
        if 0 <= value <= limit or -(limit + 1) // 2 <= value < 0:
            return size
    return MAX_INT_BYTES


def _str_bytes(length: int) -> int:
    header = 1 if length < 32 else 2 if length < 0x100 else 3 if length < 0x1_0000 else 5
    return header + length


def _container_header(count: int) -> int:
    return 1 if count < 16 else 3 if count < 0x1_0000 else 5


def _value_bytes(value: object) -> int:
    return len(msgspec.msgpack.encode(value))


def _max_bytes(info: mi.Type, where: str) -> int:
    if isinstance(info, mi.NoneType | mi.BoolType):
        return 1
    if isinstance(info, mi.FloatType):
        return MAX_INT_BYTES
    if isinstance(info, mi.IntType):
        low = info.ge if info.ge is not None else (info.gt + 1 if info.gt is not None else None)
        high = info.le if info.le is not None else (info.lt - 1 if info.lt is not None else None)
        if low is None or high is None:
            return MAX_INT_BYTES
        return max(_int_bytes(low), _int_bytes(high))
    if isinstance(info, mi.LiteralType):
        return max(_value_bytes(v) for v in info.values)
    if isinstance(info, mi.EnumType):
        return max(_value_bytes(member.value) for member in info.cls)
    if isinstance(info, mi.StrType) and info.max_length is not None:
        return _str_bytes(UTF8_MAX_BYTES_PER_CHAR * info.max_length)
    if isinstance(info, mi.UnionType):
        return max(_max_bytes(t, where) for t in info.types)
    if isinstance(info, mi.StructType) and not info.array_like:
        return _container_header(len(info.fields)) + sum(
            _value_bytes(f.encode_name) + _max_bytes(f.type, f"{where}.{f.name}") for f in info.fields)
    raise TypeError(f"{where}: {type(info).__name__} has no bounded MessagePack size")


@functools.cache
def max_encoded_size(struct: type[msgspec.Struct]) -> int:
    """The most bytes `msgspec.msgpack.encode(x)` can take for any valid instance `x` of `struct`."""
    info: Any = mi.type_info(struct)
    return _max_bytes(info, struct.__name__)
