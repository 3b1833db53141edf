"""`python -m hubs HUB --config hubs.toml`: one hub process (hubs/process.py)."""

import sys

from hubs.process import main

if __name__ == "__main__":  # not when a spawned child process re-imports the main module
    sys.exit(main())
