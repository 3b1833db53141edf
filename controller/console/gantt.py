"""The current run's timeline as a text Gantt chart: the same `Timeline` (controller/timeline/model.py) that
`hubctl timeline` draws, a row of character cells per lane.

Each cell is `end / width` seconds of the run. An ability's span is `█` (blue done, orange aborted,
grey still running), an operation's state `█` while executing (cyan), `─` once finished (green), `█`
red in error; an unhealthy period `░` red where nothing else is drawn, a fault `X`. The top row marks
each plan request (`|` the first, `▼` a replan); the last few plans follow with their reasons.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from rich.text import Text

from common.model import Model
from controller.recording.reader import list_runs, open_run
from controller.timeline.model import MarkerKind, Span, Timeline, build_timeline

NAME_WIDTH = 18
PLANS_SHOWN = 6
ABILITY_STYLES = {"done": "blue", "aborted": "dark_orange", "running": "grey50"}
OPERATION_CELLS = {"executing": ("█", "cyan"), "finished": ("─", "green"), "error": ("█", "bold red")}

Cell = tuple[str, str]  # character, style
BLANK: Cell = (" ", "")


def current_timeline(directory: Path, models: dict[str, Model]) -> Timeline | None:
    """The timeline of the newest run recorded in `directory` (being written or not); None without one.
    `models` caches each run's model by its reference (loading one costs more than reading a run)."""
    runs = [r for r in list_runs(directory) if not r.problem]
    if not runs:
        return None
    with open_run(runs[-1].path) as run:
        reference = run.meta.model
        if reference not in models:
            from common.stations import load_model

            models[reference] = load_model(reference)
        return build_timeline(run, models[reference])


def _cells(spans: Iterable[Span], width: int, per_cell: float, look: dict[str, Cell], row: list[Cell]) -> None:
    for span in spans:
        first = min(width - 1, int(span.start / per_cell))
        last = min(width - 1, max(first, int(span.end / per_cell - 1e-9)))
        for c in range(first, last + 1):
            row[c] = look.get(span.outcome, ("█", ""))


def gantt_lines(timeline: Timeline, width: int) -> list[Text]:
    """The chart in `width` columns (lane names included), then the last plans' reasons."""
    cells = max(10, width - NAME_WIDTH - 1)
    per_cell = max(timeline.end, 1e-3) / cells
    rows: dict[str, list[Cell]] = {lane: [BLANK] * cells for lane in timeline.lanes}
    for period in timeline.unhealthy:
        if period.lane in rows:
            _cells([Span(period.lane, "", period.start, period.end, "unhealthy")], cells, per_cell,
                   {"unhealthy": ("░", "red")}, rows[period.lane])
    abilities = {k: ("█", style) for k, style in ABILITY_STYLES.items()}
    for lane, row in rows.items():
        _cells((s for s in timeline.abilities if s.lane == lane), cells, per_cell, abilities, row)
        _cells((s for s in timeline.operation_spans if s.lane == lane), cells, per_cell, OPERATION_CELLS, row)
    for fault in timeline.faults:
        if fault.lane in rows:
            rows[fault.lane][min(cells - 1, int(fault.t / per_cell))] = ("X", "bold red")
    header: list[Cell] = [BLANK] * cells
    for marker in timeline.plans:
        mark: Cell = ("|", "") if marker.kind is MarkerKind.PLAN else ("▼", "dark_orange")
        header[min(cells - 1, int(marker.t / per_cell))] = mark
    lines = [_line(f"plans, {timeline.end:.0f} s", header)]
    lines += [_line(lane, row) for lane, row in rows.items()]
    for number, marker in list(enumerate(timeline.plans, start=1))[-PLANS_SHOWN:]:
        lines.append(Text(f"{number:>3}  {marker.t:7.1f} s  {marker.kind}: {marker.text}",
                          "dark_orange" if marker.kind is MarkerKind.REPLAN else ""))
    lines += [Text(f"  fault {m.t:7.1f} s  {m.text}", "bold red") for m in timeline.faults[-PLANS_SHOWN:]]
    if timeline.note:
        lines.append(Text(timeline.note, "yellow"))
    return lines


def _line(name: str, row: list[Cell]) -> Text:
    text = Text(name[:NAME_WIDTH].ljust(NAME_WIDTH) + " ")
    run, style = "", ""
    for char, cell_style in row:
        if cell_style != style and run:
            text.append(run, style)
            run = ""
        run, style = run + char, cell_style
    text.append(run, style)
    return text
