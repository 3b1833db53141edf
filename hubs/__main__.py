"""`python -m hubs HUB --config hubs.toml`: one hub process (hubs/main.py)."""


from common.plumbing.lifecycle import exit_process
from hubs.main import main

if __name__ == "__main__":  # not when a spawned child process re-imports the main module
    exit_process(main())
