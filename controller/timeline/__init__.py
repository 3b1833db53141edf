"""A recorded run as a Gantt chart: model.py (spans, markers, shaded periods from a recording), render.py
(matplotlib: SVG, PNG, one self-contained HTML file)."""
