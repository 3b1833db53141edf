"""Station models; `hubs.toml` names the one a deployment runs as `package.module:function`."""

from __future__ import annotations

import importlib

from common.model import Model

DEFAULT_MODEL = "common.stations.engine_assembly:build_model"


class ModelLoadError(Exception):
    """A model reference that does not give a Model; the message says which part is wrong (a caller that
    read the reference from a file adds where: `StationConfig.load_model`)."""


def load_model(reference: str = DEFAULT_MODEL) -> Model:
    """The model a `module:function` reference builds (`module:attribute` naming a Model works too)."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise ModelLoadError(f"model reference {reference!r} must look like 'package.module:function'")
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
