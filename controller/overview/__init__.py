"""The supervisors' read-only station overview: a web page served by a process of its own (`hubctl overview`).

picture.py   what the page shows, pure functions of the controller's status, its plan and the run's timeline
reader.py    the overview's only handle on the bus: subscriptions and the queries that only read
feed.py      the station as the overview knows it, kept current from the bus and the recording
runfile.py   the Gantt chart's data: the station's newest recorded run
web.py       the aiohttp server: the page, its static files, its server-sent events; GET only
main.py      the process (`hubctl overview`, `python -m controller.overview`)
site.py      the line's site view: a row per station of a line (served by `hubctl line up|overview`)
static/      the page: HTML, CSS and a small script that draws the tables and the Gantt chart in SVG
"""
