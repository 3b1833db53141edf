"""Station models; `hubs.toml` names the one a deployment runs as `package.module:function`."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from common.model import Model

DEFAULT_MODEL = "common.stations.engine_assembly:build_model"


class ModelLoadError(Exception):
    """A model reference that does not give a Model; the message says which part is wrong (a caller that
    read the reference from a file adds where: `StationConfig.load_model`)."""


def is_file_reference(reference: str) -> bool:
    """`model.py:build_model`: a model module given as a file (next to its hubs.toml), not an installed module."""
    return reference.partition(":")[0].endswith(".py")


def resolve_model_reference(reference: str, base: Path) -> str:
    """A file reference made absolute against `base` (the directory of the hubs.toml that names it), so that
    every process given the reference (the planner worker, a replay) imports the same file."""
    if not is_file_reference(reference):
        return reference
    file, _, attribute = reference.partition(":")
    return f"{(base / file).resolve()}:{attribute}"


def _import_file(file: str) -> ModuleType:
    path = Path(file)
    if not path.is_file():
        raise ModelLoadError(f"no model file {file}")
    # One module per file, whatever its name: two stations may both call theirs model.py.
    name = f"statehub_station_{path.stem}_{hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:8]}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ModelLoadError(f"cannot import {file} as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # a station module that fails to import is reported, whatever it raised
        del sys.modules[name]
        raise ModelLoadError(f"cannot import {file}: {type(exc).__name__}: {exc}") from exc
    return module


def load_model(reference: str = DEFAULT_MODEL) -> Model:
    """The model a `module:function` reference builds (`module:attribute` naming a Model works too); the module
    may be a file, `path/to/model.py:function` (relative to the working directory: `StationConfig` makes a
    reference of hubs.toml absolute against the file's directory)."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise ModelLoadError(f"model reference {reference!r} must look like 'package.module:function' "
                             f"or 'file.py:function'")
    if is_file_reference(reference):
        module = _import_file(module_name)
    else:
        try:
            module = importlib.import_module(module_name)
        except Exception as exc:  # a station module that fails to import is reported, whatever it raised
            raise ModelLoadError(f"cannot import module {module_name!r}: {type(exc).__name__}: {exc}") from exc
    try:
        target = getattr(module, attribute)
    except AttributeError:
        raise ModelLoadError(f"module {module_name!r} has no attribute {attribute!r}") from None
    model = target() if callable(target) and not isinstance(target, Model) else target
    if not isinstance(model, Model):
        raise ModelLoadError(f"{reference} gave a {type(model).__name__}, not a Model")
    return model
