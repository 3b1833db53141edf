"""pytest plugin for the generated model-based tests: keep them in a project's suite.

Enable it in a conftest.py (or a test module) with

    pytest_plugins = ["deploy.modeltest.pytest_plugin"]

and use the `model_test` fixture, a factory that runs one resource's test against a
running hub and fails the test with the report (the minimal failing sequence):

    def test_nutrunner_hub(model_test, tool_hub):          # tool_hub: your fixture starting the hub
        model_test(Target.from_config("hubs.toml", loopback_port=tool_hub.port), "nr")

`model_test(..., expect_pass=False)` returns the Report instead of failing, to assert on
a failure. `--modeltest-examples N` and `--modeltest-deadline S` override every call's
options (e.g. a long nightly run). `deploy.modeltest.model_based_test` builds a plain
test function instead of using the fixture.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from .runner import ModelTest, ModelTestFailed, Report, Target, run_model_test
from .session import Options

__all__ = ["ModelTest", "model_test", "pytest_addoption"]


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("modeltest", "model-based tests of hubs (deploy.modeltest)")
    group.addoption("--modeltest-examples", type=int, default=None,
                    help="command sequences per model-based test (overrides each test's own)")
    group.addoption("--modeltest-deadline", type=float, default=None,
                    help="seconds per expectation in model-based tests (overrides each test's own)")


@pytest.fixture
def model_test(request: pytest.FixtureRequest) -> ModelTest:
    """Run a generated model-based test: `model_test(target, resource, options=None, *, reset=None,
    expect_pass=True)`; fails the test with the report unless `expect_pass=False`."""
    examples = request.config.getoption("--modeltest-examples", default=None)
    deadline = request.config.getoption("--modeltest-deadline", default=None)

    def run(target: Target, resource: str, options: Options | None = None, *,
            reset: Callable[[], None] | None = None, expect_pass: bool = True) -> Report:
        options = options or Options()
        if examples is not None:
            options = dataclasses.replace(options, examples=examples)
        if deadline is not None:
            options = dataclasses.replace(options, deadline=deadline)
        report = run_model_test(target, resource, options, reset=reset, say=print)
        if expect_pass and (report.aborted is not None or not report.passed):
            raise ModelTestFailed(report)
        return report

    return run
