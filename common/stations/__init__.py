"""Station models; `hubs.toml` names the one a deployment runs as `package.module:function`."""

from __future__ import annotations

import importlib

from common.model import Model

DEFAULT_MODEL = "common.stations.engine_assembly:build_model"


class ModelLoadError(Exception):
    pass


def load_model(reference: str = DEFAULT_MODEL) -> Model:
    """The model a `module:function` reference builds; errors say which part is wrong."""
    module_name, _, function_name = reference.partition(":")
    if not module_name or not function_name:
        raise ModelLoadError(f"model reference {reference!r} must look like 'package.module:function'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ModelLoadError(f"cannot import station module {module_name!r} (from {reference!r}): {exc}") from exc
    factory = getattr(module, function_name, None)
    if not callable(factory):
        raise ModelLoadError(f"station module {module_name!r} has no function {function_name!r}")
    model = factory()
    if not isinstance(model, Model):
        raise ModelLoadError(f"{reference} returned {type(model).__name__}, not a Model")
    return model
