"""`python -m controller --config hubs.toml`: the controller process (controller/main.py)."""

import sys

from controller.main import main

if __name__ == "__main__":  # not when the planner's spawned process re-imports the main module
    sys.exit(main())
