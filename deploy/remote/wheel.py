"""Building the statehub wheel that `hubctl deploy` installs, reproducibly.

The same source gives the same wheel, byte for byte, so that its hash names a release
and a redeploy of unchanged code finds the release already on the target:

* the source is copied to a clean temporary directory first: setuptools keeps `build/`
  and `*.egg-info` between builds, and a module deleted from the tree would otherwise
  live on in every later wheel (and the checkout stays free of build litter);
* SOURCE_DATE_EPOCH pins the timestamps inside the zip.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

# 1980-01-01, the earliest time a zip can hold.
SOURCE_DATE_EPOCH = "315532800"
_IGNORE = shutil.ignore_patterns(".*", "__pycache__", "*.pyc", "build", "dist", "*.egg-info", "var", "venv")
_WHEEL_NAME = re.compile(r"^(?P<name>[A-Za-z0-9_.]+)-(?P<version>[A-Za-z0-9_.!+]+)(-\d[^-]*)?-[^-]+-[^-]+-[^-]+\.whl$")


class WheelError(RuntimeError):
    pass


@dataclass(frozen=True)
class Wheel:
    path: Path
    version: str
    sha256: str

    @property
    def name(self) -> str:
        return self.path.name


def inspect_wheel(path: Path) -> Wheel:
    """Version (from the file name, PEP 427) and hash of a built wheel."""
    match = _WHEEL_NAME.match(path.name)
    if not match:
        raise WheelError(f"{path}: not a wheel file name (expected NAME-VERSION-PY-ABI-PLATFORM.whl)")
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise WheelError(f"cannot read wheel {path}: {exc.strerror}") from None
    return Wheel(path, match.group("version"), digest)


def build_command(source: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--disable-pip-version-check",
            "-w", str(out), str(source)]


def build_wheel(project: Path, out: Path) -> Wheel:
    """Build the project's wheel into `out`; raises WheelError with pip's output on failure."""
    if not (project / "pyproject.toml").is_file():
        raise WheelError(f"{project}: no pyproject.toml (run hubctl deploy in the statehub checkout, "
                         f"or give --source DIR or --wheel FILE)")
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="statehub-src-") as tmp:
        source, built = Path(tmp) / "src", Path(tmp) / "wheels"
        shutil.copytree(project, source, ignore=_IGNORE)
        env = dict(os.environ, SOURCE_DATE_EPOCH=SOURCE_DATE_EPOCH)
        result = subprocess.run(build_command(source, built), capture_output=True, text=True, env=env)
        if result.returncode != 0:
            raise WheelError(f"building the wheel of {project} failed (pip exit {result.returncode}):\n"
                             f"{(result.stderr or result.stdout).strip()}")
        wheels = list(built.glob("*.whl"))
        if len(wheels) != 1:
            raise WheelError(f"pip built {len(wheels)} wheels from {project}, expected one")
        target = out / wheels[0].name
        shutil.move(wheels[0], target)
    return inspect_wheel(target)


def default_source() -> Path:
    """The checkout this hubctl runs from (an editable install, `./dev`), else the working directory."""
    here = Path(__file__).resolve().parents[2]
    return here if (here / "pyproject.toml").is_file() else Path.cwd()
