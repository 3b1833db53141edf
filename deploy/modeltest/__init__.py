"""Model-based tests of hubs (DESIGN.md §9): generated from a resource model, run over Zenoh.

The test acts like the controller: it sends a resource's hub random command sequences
(Hypothesis), each command with a sequence number and its own controller id, re-sent at
the command rate, and checks every state the hub publishes against the model:

(a) the hub mirrors each command within the deadline;
(b) an enabled effect transition shows one of its outcomes within the deadline;
(c) every change of the measured variables is explained by enabled effect transitions.

A failure shrinks to a minimal command sequence. Modules: `oracle` (what the model
allows), `checker` (judges observed states), `link` (Zenoh), `session` (one example),
`runner` (Hypothesis, reports), `cli` (`hubctl test`), `pytest_plugin`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .checker import Finding
    from .link import BusThread, LinkError
    from .oracle import ResourceOracle
    from .runner import ModelTestFailed, Report, Target, model_based_test, run_model_test
    from .session import ExampleFailure, Options, SessionAborted, Step

# Imported on first use: hubctl imports `deploy.modeltest.cli` at start-up, and that must not
# pull in Hypothesis and Zenoh.
_EXPORTS = {
    "Finding": "checker", "BusThread": "link", "LinkError": "link", "ResourceOracle": "oracle",
    "ModelTestFailed": "runner", "Report": "runner", "Target": "runner", "model_based_test": "runner",
    "run_model_test": "runner", "ExampleFailure": "session", "Options": "session", "SessionAborted": "session",
    "Step": "session",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{module}", __name__), name)


__all__ = [
    "BusThread",
    "ExampleFailure",
    "Finding",
    "LinkError",
    "ModelTestFailed",
    "Options",
    "Report",
    "ResourceOracle",
    "SessionAborted",
    "Step",
    "Target",
    "model_based_test",
    "run_model_test",
]
