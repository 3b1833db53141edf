"""The tracker feed, statehub's protocol for people trackers (no standard one exists).

The tracker listens on TCP (`DEFAULT_PORT`); each client receives one UTF-8 JSON object
per line, at 10-30 Hz, also when nobody is in view (the frames are the heartbeat)::

    {"v": 1, "seq": 42, "t": 1712345678.123, "people": [{"id": 1, "x": 2.10, "y": 0.35}]}

Shared by the driver (`hubs.drivers.camera_tracker`) and the simulator
(`hubs.sim.camera_tracker`).
"""

from __future__ import annotations

DEFAULT_PORT = 7001
VERSION = 1
