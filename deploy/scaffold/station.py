"""`hubctl new-station NAME`: a station project that runs as it is, to be grown device by device.

The project is a Python package of its own (statehub is its dependency):

    NAME/
      pyproject.toml       the package; its entry points register the station's drivers
      hubs.toml            which hub serves which resource; every device "emulate"
      NAME/model.py        the model: one example resource (a clamp) with ability/Phase, operations
      NAME/devices/        models of device types of its own (`hubctl new-device` stubs)
      NAME/drivers/        their drivers (`hubctl new-device` skeletons)
      tests/               the station's tests (statehub's pytest fixtures)

Installed (`pip install -e NAME`), `hubctl up` runs it from its directory.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from .files import Changes, ScaffoldError, check_name, render


def new_station(name: str, directory: Path | None = None) -> list[str]:
    """Write the project of station `name` into `directory` (default ./NAME); what was done and what next."""
    check_name("station", name)
    existing = importlib.util.find_spec(name)
    if existing is not None:
        where = existing.origin or ", ".join(existing.submodule_search_locations or ())
        raise ScaffoldError(f"a Python module named {name!r} is importable already ({where}): the station's package "
                            f"would be hidden behind it or hide it; choose another name")
    root = (directory if directory is not None else Path(name)).resolve()
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise ScaffoldError(f"{root} exists and is not an empty directory: give another --dir")
    changes = Changes(root, [f"station {name}: a new project in {root}"])
    files = {
        "pyproject.toml": render("pyproject.toml", name=name),
        "hubs.toml": render("hubs.toml", name=name),
        f"{name}/__init__.py": f'"""The {name} station: its model, its device drivers (statehub)."""\n',
        f"{name}/model.py": render("model.py", name=name),
        f"{name}/devices/__init__.py": '"""Models of device types of this station\'s own (`hubctl new-device`)."""\n',
        f"{name}/drivers/__init__.py": '"""Drivers of device types of this station\'s own (`hubctl new-device`)."""\n',
        "tests/conftest.py": render("conftest.py", name=name),
        "tests/test_station.py": render("test_station.py", name=name),
    }
    for relative, text in files.items():
        changes.create(root / relative, text)
    changes.lines += [
        "next:",
        f"  cd {root}",
        "  python -m pip install --no-build-isolation -e .   # the package, into statehub's environment",
        "  hubctl up                                        # the station, every device emulated",
        "  python -m pytest                                 # its tests",
        "  hubctl new-device clamp                          # a driver skeleton for the clamp, and its test",
    ]
    return changes.lines
