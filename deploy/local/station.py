"""`hubctl up`: the whole station on this machine, as separate processes over Zenoh on loopback.

The controller and every hub of hubs.toml run as their own processes (what systemd
runs on the real station), with emulated devices by default, restarted as their units
restart them (supervisor.py). This process watches the controller's status and prints
progress, then a summary; Ctrl-C stops everything. `chaos` kills some of them on the way
(chaos.py). With orders (`--orders N --mix ...`, or [production] of hubs.toml) the controller runs one
product after another; this prints a line per finished order and, at the end, the throughput.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import shutil
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from common.bus.station_net import security_banner
from common.bus.zenoh_bus import ZenohBus
from common.config.hubs_toml import StationConfig, load_station
from common.config.modes import DeviceMode, Execution
from common.config.production import ProductionPlan
from common.config.security import operator_identity
from common.model import Model, OperationState
from common.plumbing.lifecycle import free_port
from common.wire.ctl import CycleInfo, Event, OrderDone, OrderFinished, OrderStarted, PlanDetails, StatusMessage
from common.wire.messages import MessageError
from controller.console.statusview import StatusFollower, fetch_plan
from controller.cycle import Bound, CycleReport, ResourceIdle
from controller.production.throughput import OrderThroughput, run_throughput, summary_lines
from deploy.remote.restart_policy import UP_RESTART, RestartPolicy
from deploy.runs.cli import timeline_after_run

from .chaos import Chaos, ChaosPlan, plan_chaos
from .done_once import check_done_once, run_recordings
from .localcerts import local_certs, watcher_zenoh_config
from .operator_pages import operator_pages
from .recordings import recording_since
from .supervisor import Child, Say, Supervisor

RUN_DIR = Path("var/up")
EMULATED_STATE = "devices"  # in the run directory: the emulated devices' values, kept across restarts of their hubs
OPERATION_LABELS = {OperationState.EXECUTING: "start", OperationState.FINISHED: "done ", OperationState.ERROR: "ERROR",
                    OperationState.INITIAL: "reset"}


class AlreadyRunning(RuntimeError):
    pass


@contextlib.contextmanager
def single_instance(run_dir: Path) -> Iterator[None]:
    run_dir.mkdir(parents=True, exist_ok=True)
    lock_path = run_dir / "up.lock"
    handle = lock_path.open("a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        owner = handle.read().strip() or "unknown"
        handle.close()
        raise AlreadyRunning(f"hubctl up is already running here ({owner}); stop it first (Ctrl-C)") from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()}, started {time.strftime('%H:%M:%S')}")
    handle.flush()
    try:
        yield
    finally:
        fcntl.flock(handle, fcntl.LOCK_UN)
        handle.close()


@dataclass
class Options:
    config: str = "hubs.toml"
    speed: float = 1.0
    seed: int = 0
    mode: DeviceMode | None = None
    real: frozenset[str] = frozenset()  # `--real RESOURCE`: these devices in mode real, whatever `mode` says
    failure: dict[str, float] = field(default_factory=dict)
    time_limit: float = 900.0
    resume: bool = False
    hold: bool = False  # the controller starts no operation: the operator starts them from `hubctl console`
    record: bool = True  # the controller records the run (controller/recording)
    run_dir: Path = RUN_DIR
    chaos: int = 0  # kill -9 this many processes at moments drawn from `seed` (chaos.py)
    chaos_plan: ChaosPlan | None = None  # these kills instead of drawing `chaos` of them
    restart: RestartPolicy = UP_RESTART  # how a process that exits is restarted (the units' policy)
    # The orders: `--orders N --mix ...` handed to the controller, which queues them on its fresh start (as it
    # queues [production] of hubs.toml without them); `production` is the plan they make, for the progress.
    orders: int | None = None
    mix: str | None = None
    production: ProductionPlan | None = None
    execution: Execution | None = None  # `--execution`: the controller's order of plan steps over hubs.toml's


def child_commands(config: StationConfig, options: Options, port: int, certs: Path | None = None) -> list[Child]:
    run_dir = options.run_dir
    secured = ["--certs", str(certs)] if certs is not None else []
    controller = [sys.executable, "-m", "controller", "--config", options.config, "--loopback-port", str(port),
                  "--db", str(run_dir / "controller.sqlite"), "--speed", str(options.speed)]
    if options.hold:
        controller.append("--hold")
    if options.orders is not None:
        controller += ["--orders", str(options.orders)] + (["--mix", options.mix] if options.mix else [])
    if options.execution is not None:
        controller += ["--execution", options.execution]
    controller += ["--run-mode", "up", "--run-seed", str(options.seed)] if options.record else ["--no-record"]
    # A restarted controller resumes from its SQLite file: only its first start may forget it.
    children = [Child("controller", controller + secured, run_dir / "controller.log",
                      first_start_args=[] if options.resume else ["--fresh"])]
    for hub in config.hubs.values():
        argv = [sys.executable, "-m", "hubs", hub.name, "--config", options.config, "--loopback-port", str(port),
                "--speed", str(options.speed), "--seed", str(options.seed),
                "--emulated-state", str(run_dir / EMULATED_STATE), *secured]
        if options.mode:
            argv += ["--mode", options.mode]
        for resource in sorted(options.real & set(hub.devices)):
            argv += ["--real", resource]
        for resource, p in options.failure.items():
            if resource in hub.devices:
                argv += ["--failure", f"{resource}={p}"]
        children.append(Child(hub.name, argv, run_dir / f"{hub.name}.log"))
    return children


class Progress:
    """Prints what changed in the controller's status: operations, and what each resource is doing."""

    def __init__(self, say: Say, total: int, model: Model | None = None) -> None:
        self.say = say
        self.total = total
        self.model = model
        self.orders_done: dict[int, OrderDone] = {}  # by order id, as the statuses reported them
        self.operations_before = 0  # the operations of the orders done: the run's progress goes on over orders
        self.op_states: dict[str, OperationState] = {}
        self.activity = ""
        self.last_activity_at = 0.0
        self.reported: set[str] = set()
        self.faults = 0  # faults in the controller's event log over the whole run, not only a status's window
        self.last_fault: Event | None = None
        self._controller = ""
        self._events_seen = 0  # the controller's events_total when its events were last read

    def _read_events(self, status: StatusMessage) -> None:
        """The events new since the last status: the newest `events_total` minus those seen, of the ones it
        carries (a status carries the last EVENT_WINDOW only, so more than that between two are missed)."""
        if status.controller != self._controller:  # a restarted controller counts from zero
            self._controller, self._events_seen = status.controller, 0
        new = max(0, status.events_total - self._events_seen)
        for event in status.events[len(status.events) - min(new, len(status.events)):]:
            if isinstance(event, OrderStarted | OrderFinished):
                self.say(f"          {status.uptime:6.1f}s  {event.text}")
            if event.fault:
                self.faults += 1
                self.last_fault = event
        self._events_seen = status.events_total

    def _read_orders(self, status: StatusMessage) -> None:
        production = status.production
        if production is None:
            return
        for done in production.recent:
            if done.order not in self.orders_done:
                self.orders_done[done.order] = done
                if self.model is not None:
                    self.operations_before += len(self.model.variant_by_name[done.variant].requested(
                        self.model.operations))

    def finished_operations(self, status: StatusMessage) -> int:
        """Operations finished over the run: those of the orders done, and the running one's so far."""
        return self.operations_before + sum(1 for op in status.operations if op.state is OperationState.FINISHED)

    def throughput_lines(self) -> list[str]:
        """Engines per hour and cycle times of the orders done, on the order book's clock."""
        done = sorted(self.orders_done.values(), key=lambda o: o.order)
        if not done:
            return []
        figures = [OrderThroughput(o.order, o.product_id, o.variant, o.started, o.finished, {}) for o in done]
        span = max(o.finished for o in done) - min(o.started for o in done)
        return summary_lines(run_throughput(figures, span))

    def update(self, status: StatusMessage, plan: PlanDetails | None = None) -> None:
        """Print what changed; `plan`: the details of the plan under way (its steps), if known."""
        say = self.say
        self._read_events(status)
        self._read_orders(status)
        done = sum(1 for op in status.operations if op.state is OperationState.FINISHED)
        for op in status.operations:
            old = self.op_states.get(op.name)
            if old == op.state:
                continue
            self.op_states[op.name] = op.state
            if old is None and op.state is OperationState.INITIAL:
                continue
            label = OPERATION_LABELS[op.state]
            extra = f"  ({op.error})" if op.error else ""
            say(f"[{done:2d}/{self.total}] {status.uptime:6.1f}s  {label}  {op.name}{extra}")
        current: dict[str, str] = {}
        under_way = status.plan
        if plan is not None and under_way is not None and plan.id == under_way.id:
            for j, step in enumerate(plan.steps):
                if not under_way.is_done(j) and step.resource not in current:
                    current[step.resource] = step.transition.split(".", 2)[1] if "." in step.transition \
                        else step.transition
        unhealthy = {h.resource: h.reason for h in status.health if not h.healthy}
        activity = " | ".join(f"{r}: {a}" for r, a in sorted(current.items()))
        now = time.monotonic()
        if activity and (activity != self.activity and now - self.last_activity_at > 1.0):
            say(f"          {status.uptime:6.1f}s  now  {activity}")
            self.activity, self.last_activity_at = activity, now
        for resource, reason in unhealthy.items():
            if resource not in self.reported:
                say(f"          {status.uptime:6.1f}s  UNHEALTHY  {resource}: {reason}")
        for healed in self.reported - set(unhealthy):
            say(f"          {status.uptime:6.1f}s  recovered  {healed}")
        self.reported = set(unhealthy)


def cycle_lines(cycle: CycleInfo | None) -> list[str]:
    """The cycle report the in-process run prints (cycle time, bound, their ratio, each resource's idle time and
    what it waited for), from the controller's last status ([] from a controller that does not report it)."""
    if cycle is None:
        return []
    first = Bound(cycle.bound_s, cycle.chain_s, cycle.busiest, cycle.busiest_work_s)
    idle = tuple(ResourceIdle(r.resource, r.idle_s, tuple(r.waits)) for r in cycle.idle)
    return CycleReport(cycle.cycle_s, cycle.bound_s, cycle.predicted_s, idle, first, cycle.busiest,
                       cycle.busiest_work_s, cycle.chain_s, cycle.apart_s, tuple(cycle.apart)).lines()


def chaos_plan(options: Options, children: list[Child], model: Model) -> ChaosPlan | None:
    if options.chaos_plan is not None:
        return options.chaos_plan
    if not options.chaos:
        return None
    return plan_chaos(options.chaos, options.seed, [c.name for c in children], run_operations(options, model))


def run_operations(options: Options, model: Model) -> int:
    """The operations the run does: every one once, or those of each order's variant."""
    if options.production is None:
        return len(model.operations)
    return sum(len(model.variant_by_name[o.variant].requested(model.operations)) for o in options.production.orders)


async def run_station(options: Options, say: Say = print) -> int:
    config, model = load_station(options.config)
    with local_certs(config) as certs:
        return await _run_station(options, say, config, model, certs)


async def _run_station(options: Options, say: Say, config: StationConfig, model: Model,
                       certs: Path | None) -> int:
    port = free_port()
    children = child_commands(config, options, port, certs)
    emulated = options.run_dir / EMULATED_STATE
    if not options.resume:  # a run starts with its devices as the model says; a restarted hub finds them as left
        shutil.rmtree(emulated, ignore_errors=True)
    emulated.mkdir(parents=True, exist_ok=True)
    keys = config.keys
    scheme = "tls" if certs is not None else "tcp"
    devices = f"{options.mode or 'as in ' + options.config}" + "".join(f", {r} real" for r in sorted(options.real))
    say(f"statehub up: station {config.station.name}, {len(config.hubs)} hubs + controller as separate processes "
        f"on 127.0.0.1:{port}, devices {devices}, speed x{options.speed}, "
        f"plans in {options.execution or config.controller.execution}")
    say(f"  {security_banner(config)}" + (f" (this run's certificates: {certs})" if certs else ""))
    say(f"  logs in {options.run_dir}/")
    console = f" --as {operator_identity(config).name} --certs {certs}" if certs else ""
    say(f"  console: hubctl console --config {options.config} --connect {scheme}/127.0.0.1:{port}{console}")
    for page in operator_pages(config, options.mode, options.real):
        say(f"  {page.line()}")
    began, began_wall = time.monotonic(), time.time()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    world = None
    if options.mode == DeviceMode.SIM:  # the simulators, coupled; each hub is told where its devices' simulators are
        from .simworld import start_world

        world = await start_world(config, model, options, port, say, certs=certs)
        if world is None:
            return 1
        for child in children:
            child.argv += world.hub_args(child.name)
    supervisor = Supervisor(children, options.restart, say)
    plan_of_chaos = chaos_plan(options, children, model)
    chaos = None
    if plan_of_chaos is not None:
        say(f"  chaos (seed {plan_of_chaos.seed}): kill -9 {plan_of_chaos.describe() or 'nothing'}")
        chaos = Chaos(plan_of_chaos, supervisor.kill, say, time.monotonic)
    await supervisor.start()
    progress = Progress(say, len(model.operations), model)
    result = 1
    last: StatusMessage | None = None
    try:
        async with ZenohBus(watcher_zenoh_config(config, model, port, certs)) as bus:
            statuses = bus.subscribe(keys.ctl("status"), coalesce=False)
            follower = StatusFollower(bus, keys)
            plan: PlanDetails | None = None
            while True:
                if stop.is_set():
                    say("interrupted: stopping the station")
                    result = 130
                    break
                if supervisor.gave_up is not None:
                    say(supervisor.gave_up.message())
                    result = 1
                    break
                if chaos is not None:
                    chaos.observe(None if last is None else progress.finished_operations(last))
                if time.monotonic() - began > options.time_limit:
                    say(f"time limit of {options.time_limit:.0f} s reached")
                    break
                try:
                    async with asyncio.timeout(0.5):
                        sample = await statuses.get()
                except TimeoutError:
                    continue
                try:
                    status = await follower.take(sample.payload)
                except MessageError as exc:
                    say(f"ignored a malformed status: {exc}")
                    continue
                if status is None:
                    continue
                last = status
                if last.plan is not None and last.plan.id and (plan is None or plan.id != last.plan.id):
                    plan = await fetch_plan(bus, keys, last.plan.id) or plan  # once per plan: its steps
                progress.update(last, plan)
                if last.finished:
                    result = 0
                    break
    finally:
        await supervisor.stop()
        if world is not None:
            await world.stop()
    elapsed = time.monotonic() - began
    if last is not None:
        done = sum(1 for op in last.operations if op.state is OperationState.FINISHED)
        say("")
        production = last.production
        done_text = (f"{production.done}/{production.done + production.queued + (production.current is not None)} "
                     f"orders" if production is not None else f"{done}/{len(last.operations)} operations")
        say(f"{'finished' if result == 0 else 'NOT finished'}: {done_text}, "
            f"{last.abilities} abilities started, {last.plans} plans, {last.replans} replans, "
            f"{last.no_plans} goals without a plan, in {elapsed:.1f} s")
        if production is not None:
            say(f"orders: {production.done} done, {production.queued} queued"
                + (f", {production.current.describe()}" if production.current is not None else ""))
            for line in progress.throughput_lines():
                say(line)
        for line in cycle_lines(last.cycle):
            say(line)
        if progress.last_fault is not None:
            say(f"faults seen: {progress.faults}; last: {progress.last_fault.text}")
        if result != 0:
            for h in last.health:
                if not h.healthy:
                    say(f"  {h.resource} ({h.hub}): {h.reason}")
    else:
        say(f"no status from the controller in {elapsed:.1f} s; see {options.run_dir}/controller.log")
    say(f"restarts: {supervisor.restart_counts()}")
    if chaos is not None:
        say(chaos.summary())
    if options.record and (chaos is not None or any(supervisor.restarts.values())):
        done_once = check_done_once(run_recordings(options.config, config.station.name, began_wall - 1.0))
        say(done_once.text())
        if done_once.failed():
            result = 1
    recording = recording_since(options.config, began_wall - 1.0) if options.record else None
    if recording is not None:
        say(f"recording: {recording} (hubctl replay {recording})")
        timeline_after_run(recording, say)
    return result


def up(options: Options, say: Say = print) -> int:
    try:
        with single_instance(options.run_dir):
            return asyncio.run(run_station(options, say))
    except AlreadyRunning as exc:
        say(f"hubctl up: {exc}")
        return 1
