"""What the console knows of the station before the controller says anything: from hubs.toml and the model.

The controller's status names operations and resources and its snapshot gives values by
path; the kind of each variable, each operation's goal and the hub and mode of each
resource come from the same hubs.toml and model the controller loads.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from common.config.hubs_toml import StationConfig
from common.config.modes import DeviceMode
from common.model import Kind, Model


@dataclass(frozen=True)
class StationInfo:
    station: str
    kinds: dict[str, Kind]  # variable path -> kind
    goals: dict[str, str] = field(default_factory=dict)  # operation -> its goal, in the model's notation
    modes: dict[str, DeviceMode] = field(default_factory=dict)  # resource -> how its device runs
    lease_ms: int = 2000
    default_connect: tuple[str, ...] = ()  # where the controller listens, as seen from its own host
    recordings: str = ""  # [controller.recording] dir: where the controller records its runs (the timeline)

    @staticmethod
    def from_station(config: StationConfig, model: Model) -> StationInfo:
        return StationInfo(
            station=config.station.name,
            kinds={path: v.kind for path, v in model.variables.items()},
            goals={op.name: str(op.goal) for op in model.operations},
            modes={resource: hub.devices[resource].mode for resource, hub in config.resources.items()},
            lease_ms=config.network.lease_ms,
            default_connect=controller_endpoints(config),
            recordings=config.controller.recording.dir,
        )


def controller_endpoints(config: StationConfig) -> tuple[str, ...]:
    """The controller's listeners, reached on this host when they listen on every interface (the console
    usually runs on the controller PC, over SSH); else where the hubs connect to."""
    listen = config.network_for("controller").listen
    local = tuple(e.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for e in listen)
    return local or tuple(config.network.connect)
