"""The whole reference station in sim mode: every driver against its protocol simulator, to completion.

Minutes long, so a benchmark rather than a test: `python tests/bench/bench_sim_station.py [--speed S]`.
Prints `hubctl up --mode sim`'s progress and its closing summary, and the wall time.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from common.config.modes import DeviceMode  # noqa: E402
from deploy.local.station import Options, run_station  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--speed", type=float, default=5.0)
    parser.add_argument("--time-limit", type=float, default=1800.0)
    args = parser.parse_args()
    began = time.monotonic()
    code = asyncio.run(run_station(Options(config=str(ROOT / "hubs.toml"), mode=DeviceMode.SIM, speed=args.speed,
                                           time_limit=args.time_limit, run_dir=ROOT / "var" / "bench-sim")))
    print(f"reference station in sim mode: exit {code}, {time.monotonic() - began:.1f} s wall")
    return code


if __name__ == "__main__":
    sys.exit(main())
