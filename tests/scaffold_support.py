"""Installing the station projects the tests generate into this venv, and removing them again.

Generated projects register entry points (group statehub.drivers) for the device types
they generate drivers for, and two installed packages giving one type are an error: the
tests generate only the projects named here, and each removes every one of them (also
one a killed run left behind) before it installs its own and after it ran. `./dev test` runs
the suite in several processes: `venv_lock` makes those tests (and any pip install into this venv)
take turns, since pip runs into one venv must not overlap and `new-station` refuses a name that is
installed.
"""

from __future__ import annotations

import contextlib
import fcntl
import subprocess
import sys
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

GENERATED = ("scaffold_cell", "my_cell")  # tests/test_scaffold.py, docs/new-station.md


def pip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", *args], text=True,
                          capture_output=True, check=True)


def uninstall_generated() -> None:
    for name in GENERATED:
        with contextlib.suppress(metadata.PackageNotFoundError):
            metadata.distribution(name)
            pip("uninstall", "--yes", "--quiet", name)


@contextlib.contextmanager
def venv_lock() -> Iterator[None]:
    """Held while a test installs into this venv or depends on what is installed there."""
    with open(Path(sys.prefix) / ".statehub-tests.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@contextlib.contextmanager
def generated_projects_removed() -> Iterator[None]:
    with venv_lock():
        uninstall_generated()
        try:
            yield
        finally:
            uninstall_generated()


def install(project: Path) -> None:
    pip("install", "--quiet", "--no-deps", "--no-build-isolation", "-e", str(project))
