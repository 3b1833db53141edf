"""Generated model-based tests: Hypothesis drives command sequences into a live hub (DESIGN.md §9).

    report = run_model_test(Target.from_config("hubs.toml", loopback_port=7447), "nr", Options(examples=20))
    print(report.describe())

or, in a test suite, `model_based_test(...)` returns a test function (see also
`deploy.modeltest.pytest_plugin`). The target is reached over Zenoh only, so the hub
may run emulated, simulated or real devices.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hypothesis import HealthCheck, Phase, Verbosity, given, seed, settings
from hypothesis import strategies as st
from hypothesis.errors import Flaky

from common.bus.station_net import tls_settings
from common.bus.zenoh_config import TlsSettings
from common.config.hubs_toml import StationConfig, load_config, load_station
from common.config.modes import NetworkMode
from common.config.security import identity_of, tls_endpoints
from common.model import Model

from .link import BusThread, LinkError, ResourceLink, shared_bus
from .oracle import ResourceOracle
from .session import ExampleFailure, Options, Session, SessionAborted

Say = Callable[[str], None]
ModelTest = Callable[..., "Report"]  # the pytest plugin's `model_test` fixture


@dataclass(frozen=True)
class Target:
    """Where the hubs are and which model to hold them to."""

    model: Model
    station: str
    listen: tuple[str, ...] = ()  # zenoh endpoints to listen on (where the controller would listen)
    connect: tuple[str, ...] = ()  # zenoh endpoints to connect to
    mode: NetworkMode = NetworkMode.PEER
    lease_ms: int = 2000
    command_rate_hz: float = 10.0
    # [security] mode "tls": the controller's certificate and the station's access control
    tls: TlsSettings | None = field(default=None, compare=False)

    @classmethod
    def of(cls, config: StationConfig, model: Model, *, loopback_port: int | None = None,
           certs: str | None = None) -> Target:
        """The station of `config`, reached as its controller would be (with its certificate in tls mode)."""
        network = (config.network_for("controller") if loopback_port is None
                   else config.loopback_network("controller", loopback_port))
        listen, connect = network.listen, network.connect
        tls = tls_settings(config, model, identity_of(config, "controller"), certs)
        if tls is not None:
            listen, connect = tls_endpoints(listen, config.path), tls_endpoints(connect, config.path)
        return cls(model, config.station.name, tuple(listen), tuple(connect), network.mode, network.lease_ms,
                   config.controller.command_rate_hz, tls)

    @classmethod
    def from_config(cls, path: str | Path, *, loopback_port: int | None = None, model: Model | None = None) -> Target:
        """The station of a hubs.toml, reached as its controller would be (its listen and connect
        endpoints, or loopback on `loopback_port`); `model` replaces the station's model (which is
        then not even imported: the hubs may run a model this process cannot import)."""
        if model is None:
            config, model = load_station(path)
        else:
            config = load_config(path)
        return cls.of(config, model, loopback_port=loopback_port)

    def bus(self) -> BusThread:
        return shared_bus(listen=self.listen, connect=self.connect, mode=self.mode, lease_ms=self.lease_ms,
                          tls=self.tls)


@dataclass
class Report:
    resource: str
    model: str
    options: Options
    passed: bool = False
    examples: int = 0  # examples that passed
    runs: int = 0  # examples run in all, shrinking included
    skipped: int = 0  # examples skipped: the device was not back in a state of the model
    resets: int = 0  # device resets (the reset callable)
    seconds: float = 0.0
    failure: ExampleFailure | None = None
    shrunk: bool = False  # the failure is Hypothesis's minimal example
    first_failure_run: int = 0
    notes: list[str] = field(default_factory=list)
    aborted: str | None = None  # the test could not go on (not a finding)

    def describe(self) -> str:
        head = f"model-based test of {self.resource} against model {self.model}"
        if self.aborted is not None:
            return f"{head}: NOT RUN to the end: {self.aborted}"
        if self.passed:
            text = (f"{head}: PASSED {self.examples} examples (up to {self.options.max_steps} commands each, "
                    f"deadline {self.options.deadline:g} s) in {self.seconds:.1f} s")
            return "\n".join([text, *self.notes])
        assert self.failure is not None
        shrink_runs = self.runs - self.first_failure_run
        lines = [f"{head}: FAILED in example {self.first_failure_run} ({shrink_runs} more runs while shrinking, "
                 f"{self.seconds:.1f} s in all)", *self.notes,
                 ("minimal failing " if self.shrunk else "failing ") + self.failure.describe()]
        return "\n".join(lines)


class ModelTestFailed(AssertionError):
    """A generated model-based test failed; `report` says how."""

    def __init__(self, report: Report) -> None:
        self.report = report
        super().__init__(report.describe())


def _hypothesis_test(session: Session, options: Options) -> Callable[[], None]:
    @settings(max_examples=options.examples, deadline=None, database=None,
              phases=(Phase.explicit, Phase.generate, Phase.shrink), report_multiple_bugs=False,
              suppress_health_check=list(HealthCheck), verbosity=Verbosity.quiet, print_blob=False)
    @given(st.data())
    def generated(data: st.DataObject) -> None:
        session.run_example(data)

    return generated if options.seed is None else seed(options.seed)(generated)


def _failure_in(exc: BaseException) -> ExampleFailure | None:
    if isinstance(exc, ExampleFailure):
        return exc
    for inner in getattr(exc, "exceptions", ()):
        found = _failure_in(inner)
        if found is not None:
            return found
    return None


def controllers_commanding(link: ResourceLink, seconds: float) -> list[str]:
    """Other controllers seen commanding the link's resource, or publishing the station's status."""
    link.listen_for_controllers(seconds)
    seen = sorted(link.foreign)
    seen += sorted(f"{c} (publishes {link.keys.ctl('status')})" for c in link.controller_status)
    return seen


def run_model_test(target: Target, resource: str, options: Options | None = None, *,
                   reset: Callable[[], None] | None = None, say: Say = print, bus: BusThread | None = None,
                   listen_for_controllers: float = 0.5) -> Report:
    """Run the generated test of `resource` against its hub; a failure shrinks to a minimal sequence.

    `reset`: bring the device back to its power-on state (e.g. restart an emulated hub); called
    before an example when the previous one failed, so that shrinking starts every example
    where the model can be. `listen_for_controllers`: seconds to listen for another controller
    commanding the resource first (the test refuses to fight one)."""
    options = options or Options()
    oracle = ResourceOracle(target.model, resource, max_effect_steps=options.max_effect_steps)
    if not oracle.resource.commands:
        raise ValueError(f"resource {resource} has no command variables: there is nothing to command")
    report = Report(resource, target.model.name, options)
    link = ResourceLink(bus or target.bus(), target.station, target.model, resource, context=oracle.context,
                        command_rate_hz=target.command_rate_hz)
    began = time.monotonic()
    link.open()
    try:
        if listen_for_controllers > 0:
            others = controllers_commanding(link, listen_for_controllers)
            if others:
                raise LinkError(f"another controller is running ({'; '.join(others)}): stop it before testing "
                                f"{resource} (two controllers would fight over the hub)")
        session = Session(link, oracle, options, reset=reset, say=say)
        try:
            _hypothesis_test(session, options)()
            report.passed = not session.failures
            if session.failures:  # failed, then passed on replay: not reproducible
                report.failure = session.failures[0]
                report.notes.append("the failure did not happen again when replayed: timing-dependent")
        except ExampleFailure as exc:
            report.failure, report.shrunk = exc, True
        except Flaky as exc:
            report.failure = _failure_in(exc) or (session.failures[0] if session.failures else None)
            if session.skipped:
                report.notes.append(
                    "not shrunk: after the failure the device stayed in a state its model cannot reach, so "
                    "the examples that followed were skipped; restart the hub (a power cycle) and run again, "
                    "or give the test a reset")
            else:
                report.notes.append("the minimal sequence did not fail again when replayed: timing-dependent")
        except SessionAborted as exc:
            report.aborted = str(exc)
        if link.foreign and report.aborted is None:
            # Another controller commanded the resource during the run: whatever failed is not a
            # finding about the hub, however the disturbance first showed.
            report.aborted = session._foreign_message(next(iter(link.foreign)))
            report.failure, report.passed = None, False
        report.examples, report.runs, report.skipped = session.passed, session.calls, session.skipped
        report.resets = session.resets
        report.first_failure_run = session.first_failure_call
        if report.failure is None and not report.passed and report.aborted is None:
            report.aborted = "the test failed without a recorded example"
    finally:
        link.close()
        report.seconds = time.monotonic() - began
    return report


def model_based_test(resource: str, target: Target | Callable[[], Target], options: Options | None = None, *,
                     reset: Callable[[], None] | None = None, say: Say = print) -> Callable[[], None]:
    """A test function (for pytest) that runs the generated test and fails with its report.

    `target` may be a callable returning the Target, so that it is built when the test runs
    (after its fixtures started the hub)."""

    def test() -> None:
        resolved = target() if callable(target) else target
        report = run_model_test(resolved, resource, options, reset=reset, say=say)
        if report.aborted is not None or not report.passed:
            raise ModelTestFailed(report)

    test.__name__ = f"test_model_based_{resource}"
    test.__doc__ = f"Model-based test of {resource}: random command sequences over Zenoh, checked against its model."
    return test
