"""`python -m hubs HUB --config hubs.toml`: one hub process (hubs/main.py)."""

import sys

from hubs.main import main

if __name__ == "__main__":  # not when a spawned child process re-imports the main module
    sys.exit(main())
