"""Loading a station model by its `module:function` reference (shared with the controller's planner worker)."""

from common.stations import DEFAULT_MODEL, ModelLoadError, load_model

__all__ = ["DEFAULT_MODEL", "ModelLoadError", "load_model"]
