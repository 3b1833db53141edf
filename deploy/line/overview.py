"""The line overview: every station's state, current product, cycle time, health, and which stations
cannot be reached, from the stations' own `ctl/status` (what `hubctl line up` prints).

A station is unreachable when no status of it came for UNREACHABLE_AFTER_S (a station controller publishes
a few times a second): its router is down, or the link to it, or the station controller itself. It runs
on by itself meanwhile; the overview says so and says when it is back.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from common.wire.ctl import StatusMessage
from common.wire.orders import ParameterValue
from controller.overview.site import SitePicture, SiteStation, StationState, station_severity

UNREACHABLE_AFTER_S = 3.0


@dataclass(frozen=True)
class StationRow:
    station: str
    state: StationState
    product: str  # the current product, "" when none
    cycle_s: float | None  # the last finished order's cycle
    done: int  # orders the station finished
    unhealthy: tuple[str, ...]  # its unhealthy resources
    # the current product's state as the previous station archived it (its order carries it)
    carried: dict[str, ParameterValue] = field(default_factory=dict)

    def text(self) -> str:
        cycle = f"{self.cycle_s:5.1f} s" if self.cycle_s is not None else "    -  "
        health = "ok" if not self.unhealthy else "UNHEALTHY " + ", ".join(self.unhealthy)
        carried = f"  carried {len(self.carried)} value{'s' if len(self.carried) > 1 else ''}" if self.carried else ""
        return f"  {self.station:<6} {self.state:<11} {self.product or '-':<22} cycle {cycle}  done {self.done:3d}  " \
               f"{health}{carried}"

    def site_station(self) -> SiteStation:
        unhealthy = list(self.unhealthy)
        return SiteStation(self.station, self.state, self.product, self.cycle_s, self.done, unhealthy,
                           dict(self.carried), station_severity(self.state, unhealthy))

    def headline(self) -> tuple[StationState, str, tuple[str, ...]]:
        """What a change of is printed as it happens."""
        return self.state, self.product, self.unhealthy


class Overview:
    def __init__(self, stations: Sequence[str]) -> None:
        self.stations = tuple(stations)
        self.statuses: dict[str, StatusMessage] = {}
        self.seen_at: dict[str, float] = {}

    def take(self, station: str, status: StatusMessage, now: float) -> None:
        self.statuses[station] = status
        self.seen_at[station] = now

    def row(self, station: str, now: float) -> StationRow:
        status = self.statuses.get(station)
        if status is None:
            return StationRow(station, StationState.WAITING, "", None, 0, ())
        production = status.production
        current = production.current if production is not None else None
        recent = production.recent if production is not None else []
        cycle = recent[-1].cycle_s if recent else None
        unhealthy = tuple(sorted(h.resource for h in status.health if not h.healthy))
        if now - self.seen_at[station] > UNREACHABLE_AFTER_S:
            state = StationState.UNREACHABLE
        else:
            state = StationState.WORKING if current is not None else StationState.IDLE
        return StationRow(station, state, current.product_id if current is not None else "", cycle,
                          production.done if production is not None else 0, unhealthy,
                          dict(current.carried) if current is not None else {})

    def rows(self, now: float) -> list[StationRow]:
        return [self.row(station, now) for station in self.stations]

    def unreachable(self, now: float) -> list[str]:
        return [r.station for r in self.rows(now) if r.state is StationState.UNREACHABLE]


def overview_text(rows: Iterable[StationRow], products_done: int, products: int, elapsed: float) -> str:
    lines = [f"line at {elapsed:6.1f} s: {products_headline(products_done, products)}"]
    lines += [row.text() for row in rows]
    return "\n".join(lines)


def products_headline(products_done: int, products: int) -> str:
    return f"{products_done}/{products} products left the last station"


def site_picture(line: str, rows: Sequence[StationRow], products_done: int, products: int) -> SitePicture:
    """What the line's web page shows (controller/overview/site.py)."""
    return SitePicture(line, products_headline(products_done, products), [row.site_station() for row in rows],
                       [row.station for row in rows if row.state is StationState.UNREACHABLE])
