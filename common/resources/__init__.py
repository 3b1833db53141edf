"""Models of the standard device types, one factory per type (variables as in docs/resource-contract.md)."""

from collections.abc import Callable, Mapping

from common.model import Duration, DurationTable, Model, Resource

from . import agv as _agv
from . import camera as _camera
from . import dock as _dock
from . import lift as _lift
from . import mir as _mir
from . import nutrunner as _nutrunner
from . import operator as _operator
from . import rfid as _rfid
from . import rsp as _rsp
from . import ur as _ur
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

# device_type -> how long one of its effects takes, as the type's module declares it.
TYPE_DURATIONS: dict[str, Duration] = {
    "nutrunner": _nutrunner.DURATION,
    "ur": _ur.DURATION,
    "rsp": _rsp.DURATION,
    "dock": _dock.DURATION,
    "lift": _lift.DURATION,
    "mir": _mir.DURATION,
    "agv": _agv.DURATION,
    "rfid": _rfid.DURATION,
    "camera": _camera.DURATION,
    "operator": _operator.DURATION,
}


def durations_of(model: Model, configured: Mapping[str, Duration] | None = None) -> DurationTable:
    """The station's effect durations (common/model/durations.py): `configured` (resource -> hubs.toml's
    `delay`) over each resource's own declaration, over its standard type's."""
    return DurationTable.build(model, type_defaults=TYPE_DURATIONS, configured=configured)


__all__ = ["FACTORIES", "TYPE_DURATIONS", "agv", "camera", "dock", "durations_of", "lift", "mir", "nutrunner",
           "operator", "rfid", "rsp", "ur"]
