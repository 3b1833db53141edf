"""A `Timeline` (model.py) drawn with matplotlib: SVG, PNG, or one self-contained HTML file (the SVG inline,
then the plans with their reasons and the faults as lists).

Lanes run top to bottom: the resources (each ability's span, unhealthy periods shaded red), then the
operations (a span per state). Plan and replan requests are vertical lines numbered at the top (their
reasons: `plan_lines`, listed in the HTML and printed by `hubctl timeline`), faults red crosses on their
lane (a dotted line across when they concern no lane, a hub gone). `render` returns where each lane was
drawn, in pixels of the PNG.
"""

from __future__ import annotations

import html
import io
from dataclasses import dataclass
from pathlib import Path

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from controller.timeline.model import MarkerKind, Timeline

DPI = 100
WIDTH_IN = 14.0
LANE_IN = 0.24
MARGIN_IN = 1.6  # title, plan numbers, time axis
FORMATS = (".html", ".svg", ".png")
BAR = 0.3  # half an operation's bar, in lanes (a band of `Drawn`)
ABILITY_BAR = 0.35
LABEL_WIDTH = 0.04  # an ability's span this share of the run wide or wider shows its name

ABILITY_COLORS = {"done": "#4878a8", "aborted": "#e08a2c", "running": "#9aa5b1"}
OPERATION_COLORS = {"executing": "#47b3c9", "finished": "#8cc084", "error": "#d1495b"}
UNHEALTHY_COLOR = "#e5383b"
REPLAN_COLOR = "#e08a2c"


@dataclass(frozen=True)
class Drawn:
    """Where the chart went, in pixels of the PNG (rows from the top)."""

    width: int
    height: int
    bands: dict[str, tuple[float, float]]  # lane -> (top row, bottom row) of the bars drawn in it
    x0: float  # column of t = 0
    x_per_s: float  # columns per second

    def column(self, t: float) -> float:
        return self.x0 + t * self.x_per_s


def figure(timeline: Timeline) -> tuple[Figure, Drawn]:
    lanes = timeline.lanes
    height_in = MARGIN_IN + LANE_IN * max(len(lanes), 1)
    fig = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    top = 1 - 0.55 / height_in
    bottom = 0.95 / height_in  # the time axis, then the legend
    ax = fig.add_axes((0.16, bottom, 0.82, top - bottom))
    row = {lane: i for i, lane in enumerate(lanes)}
    end = max(timeline.end, 1e-3)
    _lanes(ax, timeline, row)
    _plans(ax, timeline, len(lanes))
    for fault in timeline.faults:
        if fault.lane in row:
            ax.plot([fault.t], [row[fault.lane]], marker="X", color=UNHEALTHY_COLOR, markersize=8, zorder=5)
        else:
            ax.axvline(fault.t, color=UNHEALTHY_COLOR, linestyle=":", linewidth=1.2, zorder=4)
    ax.set_ylim(len(lanes) - 0.5, -0.5)
    ax.set_xlim(0, end * 1.01)
    ax.set_yticks(range(len(lanes)), lanes, fontsize=7)
    ax.set_xlabel("seconds since the run's start (controller clock)", fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    ax.axhline(len(timeline.resources) - 0.5, color="#333333", linewidth=0.8)
    ax.grid(axis="x", color="#dddddd", linewidth=0.5)
    ax.set_axisbelow(True)
    fig.suptitle(f"{timeline.station}: run {timeline.run}, {timeline.end:.1f} s, {len(timeline.abilities)} abilities, "
                 f"{len(timeline.plans)} plans, {len(timeline.faults)} faults", fontsize=9, y=1 - 0.12 / height_in)
    ax.legend(handles=_legend(), loc="upper center", bbox_to_anchor=(0.5, -0.5 / (top - bottom) / height_in),
              fontsize=7, ncols=8, frameon=False)
    fig.canvas.draw()
    to_pixels = ax.transData
    height_px = fig.bbox.height
    bands = {}
    for lane, i in row.items():
        (_, y_top), (_, y_bottom) = to_pixels.transform([(0, i - BAR), (0, i + BAR)])
        bands[lane] = (height_px - y_top, height_px - y_bottom)
    (x0, _), (x1, _) = to_pixels.transform([(0, 0), (1, 0)])
    return fig, Drawn(round(fig.bbox.width), round(height_px), bands, x0, x1 - x0)


def _lanes(ax: Axes, timeline: Timeline, row: dict[str, int]) -> None:
    for period in timeline.unhealthy:
        if period.lane in row:
            ax.broken_barh([(period.start, period.end - period.start)], (row[period.lane] - 0.5, 1.0),
                           facecolors=UNHEALTHY_COLOR, alpha=0.25, hatch="///", edgecolor=UNHEALTHY_COLOR, zorder=1)
    wide = timeline.end * LABEL_WIDTH
    for span in timeline.abilities:
        ax.broken_barh([(span.start, max(span.end - span.start, 0.0))], (row[span.lane] - ABILITY_BAR, 2 * ABILITY_BAR),
                       facecolors=ABILITY_COLORS.get(span.outcome, "#888888"), edgecolor="white", linewidth=0.4,
                       zorder=2)
        if span.end - span.start >= wide:
            ax.text(span.start + (span.end - span.start) / 2, row[span.lane], span.label, ha="center",
                    va="center", fontsize=5, color="white", clip_on=True, zorder=3)
    for span in timeline.operation_spans:
        if span.lane in row:
            ax.broken_barh([(span.start, max(span.end - span.start, 0.0))], (row[span.lane] - BAR, 2 * BAR),
                           facecolors=OPERATION_COLORS.get(span.outcome, "#888888"), zorder=2)


def _plans(ax: Axes, timeline: Timeline, lanes: int) -> None:
    for number, marker in enumerate(timeline.plans, start=1):
        color = "#333333" if marker.kind is MarkerKind.PLAN else REPLAN_COLOR
        ax.axvline(marker.t, color=color, linestyle="--", linewidth=0.7, alpha=0.8, zorder=3)
        ax.annotate(str(number), (marker.t, -0.5), xytext=(0, 2), textcoords="offset points",
                    ha="center", va="bottom", fontsize=6, color=color, annotation_clip=False)


def _legend() -> list[Patch]:
    return ([Patch(color=c, label=f"ability {k}") for k, c in ABILITY_COLORS.items()]
            + [Patch(color=c, label=k) for k, c in OPERATION_COLORS.items()]
            + [Patch(color=UNHEALTHY_COLOR, alpha=0.3, label="unhealthy"),
               Patch(color=REPLAN_COLOR, label="replan (numbered)")])


def plan_lines(timeline: Timeline, limit: int | None = None) -> list[str]:
    """The plans as the chart numbers them: `3  t=5.3 s  replan: goals changed -> 233 steps (greedy)`."""
    lines = [f"{n:>3}  t={m.t:.1f} s  {m.kind}: {m.text}" for n, m in enumerate(timeline.plans, start=1)]
    if limit is not None and len(lines) > limit:
        lines = [*lines[:limit], f"     ... and {len(lines) - limit} more"]
    return lines


def render(timeline: Timeline, out: str | Path) -> Drawn:
    """Draw `timeline` into `out`: .svg, .png, or .html (one file: the SVG inline, then plans and faults)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{out}: the timeline is drawn as {', '.join(FORMATS)}, not {suffix or 'no suffix'}")
    fig, drawn = figure(timeline)
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".html":
        svg = io.StringIO()
        fig.savefig(svg, format="svg")
        out.write_text(_html(timeline, svg.getvalue()), encoding="utf-8")
    else:
        fig.savefig(out, format=suffix[1:], dpi=DPI)
    return drawn


def _html(timeline: Timeline, svg: str) -> str:
    inline = svg[svg.index("<svg"):]  # without the XML prolog and doctype: it sits inside the HTML
    title = html.escape(f"{timeline.station}: run {timeline.run}")
    plans = "".join(f"<li>{html.escape(line.strip())}</li>" for line in plan_lines(timeline))
    faults = "".join(f"<li>t={m.t:.1f} s {html.escape(m.text)}</li>" for m in timeline.faults) or "<li>none</li>"
    unhealthy = "".join(f"<li>{html.escape(p.lane)}: {p.start:.1f}-{p.end:.1f} s, {html.escape(p.reason)}</li>"
                        for p in timeline.unhealthy) or "<li>none</li>"
    note = f"<p><em>{html.escape(timeline.note)}</em></p>" if timeline.note else ""
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{title}</title>"
            "<style>body{font-family:sans-serif;margin:1em}svg{max-width:100%;height:auto}"
            "li{font-family:monospace;font-size:12px}</style></head><body>"
            f"<h1>{title}</h1>{note}{inline}<h2>Plans</h2><ol>{plans}</ol><h2>Faults</h2><ul>{faults}</ul>"
            f"<h2>Unhealthy</h2><ul>{unhealthy}</ul></body></html>\n")
