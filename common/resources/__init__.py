"""Models of the standard device types, one factory per type (variables as in docs/resource-contract.md)."""

from collections.abc import Callable

from common.model import Resource

from .agv import agv
from .camera import camera
from .dock import dock
from .lift import lift
from .mir import mir
from .nutrunner import nutrunner
from .operator import operator
from .rfid import rfid
from .rsp import rsp
from .ur import ur

# device_type -> factory, for tools that build a resource from a type name.
FACTORIES: dict[str, Callable[..., Resource]] = {
    "nutrunner": nutrunner,
    "ur": ur,
    "rsp": rsp,
    "dock": dock,
    "lift": lift,
    "mir": mir,
    "agv": agv,
    "rfid": rfid,
    "camera": camera,
    "operator": operator,
}

__all__ = ["FACTORIES", "agv", "camera", "dock", "lift", "mir", "nutrunner", "operator", "rfid", "rsp", "ur"]
