"""Helpers for the UR tests: start the fake controller process on its own loopback address."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
HOME = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]
POSES: dict[str, dict[str, list[float]]] = {
    "home": {"q": HOME},
    "at_bolt1": {"q": [0.6, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]},
    "at_dock": {"tcp": [0.5, -0.3, 0.4, 0.0, 3.1416, 0.0]},
}


class FakeUr:
    """``python -m hubs.sim.ur_rtde_fake`` on ``host``; kill and start again at will."""

    def __init__(self, host: str, *args: str) -> None:
        self.host = host
        self.args = args
        self.proc: subprocess.Popen[str] | None = None

    def start(self, attempts: int = 3) -> FakeUr:
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        cmd = [sys.executable, "-m", "hubs.sim.ur_rtde_fake", "--host", self.host, *self.args]
        for attempt in range(attempts):
            with tempfile.TemporaryFile("w+") as errors:
                self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=errors, text=True, env=env, cwd=REPO)
                assert self.proc.stdout is not None
                line = self.proc.stdout.readline()
                if line.strip() == f"ready {self.host}":
                    return self
                self.kill()
                errors.seek(0)
                why = errors.read().strip().splitlines()[-1:] or [repr(line)]
            if attempt + 1 == attempts:
                raise RuntimeError(f"fake controller on {self.host} did not start: {why[0]}")
            time.sleep(0.5)  # e.g. the previous controller's port not released yet
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.proc = None

    def command(self, **request: Any) -> dict[str, Any]:
        """One request on the fake's command port (side channel)."""
        deadline = time.monotonic() + 5
        while True:
            try:
                with socket.create_connection((self.host, 30099), timeout=2) as sock:
                    sock.sendall(json.dumps(request).encode() + b"\n")
                    reply: dict[str, Any] = json.loads(sock.makefile().readline())
                    return reply
            except ConnectionError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)


def ur_params(host: str, backend: str = "sim", **extra: Any) -> dict[str, Any]:
    return {
        "host": host,
        "poses": POSES,
        "motion_backend": backend,
        "joint_speed": 3.0,
        "tcp_speed": 1.0,
        "reissue_after": 0.3,
        "reconnect_min": 0.05,
        "reconnect_max": 0.5,
        # The fake runs in another process: on a loaded 2-core machine it can miss a few of its 2 ms
        # cycles. Tests of a silent robot freeze it outright; the others must not read a stall as a loss.
        "stale_after": 1.0,
        **extra,
    }
