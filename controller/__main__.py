"""`python -m controller --config hubs.toml`: the controller process (controller/main.py)."""


from common.plumbing.lifecycle import exit_process
from controller.main import main

if __name__ == "__main__":  # not when the planner's spawned process re-imports the main module
    exit_process(main())
