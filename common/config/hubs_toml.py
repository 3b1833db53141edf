"""The station's deployment file (`hubs.toml`): schema, loader and checks.

Schema (every key not listed is an error, except a device's driver parameters)::

    [station]
    name  = "engine_assembly"                              # key prefix of every message
    model = "common.stations.engine_assembly:build_model"  # module:attribute, a Model or a function returning one

    [network]                    # defaults for every process
    mode     = "peer"            # "peer": direct links (the controller listens, hubs connect to it)
                                 # "client": every process connects to zenoh routers
    listen   = []                # zenoh endpoints a process listens on ([] = none)
    connect  = ["tcp/decs.local:7447"]   # zenoh endpoints a process connects to
    lease_ms = 2000              # a frozen process is declared gone after this long (>= 100)
    max_message_bytes = 4194304  # a larger message is dropped by zenoh on receipt (>= 65536)

    [controller]
    host             = "decs"                    # machine it runs on
    name             = "controller"              # its id in commands (`controller` field)
    command_rate_hz  = 10                        # commands are re-sent at this rate (and at once on change)
    tick_rate_hz     = 20                        # engine ticks at this rate (and on every state change)
    db               = "var/controller.sqlite"   # persisted estimated state, relative to the working dir
    mirror_timeout_s = 1.0                       # mirror may lag the command this long before unhealthy
    stale_after_s    = 0.5                       # a resource state older than this is stale
    execution        = "trace"                   # how a plan's steps wait for each other: "trace" (shared
                                                 # variables), "partial_order" (causal links), "sequence" (one by one);
                                                 # `hubctl up --execution` overrides it (controller/deorder.py)
    listen  = ["tcp/0.0.0.0:7447"]               # optional: replaces [network].listen for the controller
    connect = []                                 # optional: replaces [network].connect for the controller
    [controller.recording]   # optional: dir = "var/runs", max_mb = 200, keep = 50 (controller/recording/settings.py)

    [security]                   # optional (common/config/security.py)
    mode = "tls"                 # "tls": mTLS on every link and access control by certificate;
                                 # "insecure" (default): plain TCP, for a single-machine `hubctl up` only
    certs = "/etc/statehub/certs"  # certificates (`hubctl certs`); default ~/.config/statehub/{station}/certs
    operators = ["operator"]     # names whose certificates have the operator role (consoles, hubctl)
    verify_names = true          # a listener's certificate must name the host connected to

    [overview]                   # optional: the supervisors' read-only page (common/config/overview.py)
    bind = "127.0.0.1:8470"      # HOST:PORT it is served on (`hubctl overview`)
    name = "overview"            # its certificate's common name in tls mode (role viewer: it may only read)

    [production]                 # optional: the orders a run queues at its start (common/config/production.py)
    mix = { full = 3, light = 1 }  # a repeating mix of the model's variants, `count` orders,
    count = 8                      # or [[production.orders]] tables: variant, product_id, parameters, count

    [hubs.pi-tool]               # one table per hub (ECU); the table name is the hub name
    host              = "pi-tool"   # machine (hostname or address) for deploy/ssh
    ssh_user          = "pi"
    rate_hz           = 50          # state publication rate (and at once on change)
    command_timeout_s = 1.0         # no command for this long: outputs to the safe state
    listen  = [...]                 # optional, replaces [network].listen for this hub
    connect = [...]                 # optional, replaces [network].connect for this hub

    [hubs.pi-tool.devices.nr]    # one table per resource the hub serves; the table name is the
    type = "nutrunner"           # resource name in the station model; type: its device type (below)
    mode = "emulate"             # "emulate" (model effects) | "sim" (driver against a simulator) | "real"
    delay = [0.1, 0.3]           # optional: seconds one of its effects takes, a number or a [min, max]
                                 # interval; overrides its model's duration (common/model/durations.py)
    bus = 1                      # anything else: driver parameters, checked by the type's driver

Device types: any. A device runs in `emulate` mode from the station model alone, whatever
its type; in `sim` or `real` mode its type needs a driver and its parameters must suit it,
which hubs/ checks (`hubs.factory.check_devices`: `hubctl config check`, `up`, `hub`), since
drivers are found in hubs/ (built in, or installed plugins).

Checks (all problems are reported at once, each as `file:line: key: message`):
unknown keys, wrong types and out-of-range numbers, missing keys, duplicate hubs
(a TOML error), a resource served by two hubs, unknown device mode, names that cannot
be key chunks. With the station model (`load_station`, or `check_against_model`): a
device whose resource the model lacks, a model resource no hub serves, a device type
differing from the model's.
"""

from __future__ import annotations

import enum
import re
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

import msgspec

from common.bus.zenoh_config import DEFAULT_MAX_MESSAGE_BYTES
from common.config.errors import ConfigError, ConfigProblem, toml_problem, toml_type
from common.config.hostnames import host_problem, user_problem
from common.config.keylines import KeyLines
from common.config.modes import DEFAULT_EXECUTION, DeviceMode, Execution, NetworkMode, SecurityMode, words
from common.config.overview import OverviewConfig, parse_bind
from common.config.production import (
    OrderEntry,
    ProductionConfig,
    config_problems,
    model_problems,
    order_table_lines,
)
from common.model import Duration, Model
from common.stations import ModelLoadError, is_file_reference, load_model, resolve_model_reference
from common.wire.keys import Keys, station_keys
from controller.recording.settings import RecordingConfig

DEVICE_TYPES = ("nutrunner", "ur", "rsp", "dock", "lift", "mir", "agv", "rfid", "camera", "operator")

Hz = Annotated[float, msgspec.Meta(gt=0)]
Seconds = Annotated[float, msgspec.Meta(gt=0)]
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


# --- typed configuration -----------------------------------------------------------------

class StationSection(msgspec.Struct, frozen=True):
    name: str
    model: str


class NetworkConfig(msgspec.Struct, frozen=True):
    mode: NetworkMode = NetworkMode.PEER
    listen: list[str] = msgspec.field(default_factory=list)
    connect: list[str] = msgspec.field(default_factory=list)
    lease_ms: Annotated[int, msgspec.Meta(ge=100)] = 2000
    max_message_bytes: Annotated[int, msgspec.Meta(ge=65536)] = DEFAULT_MAX_MESSAGE_BYTES


class SecurityConfig(msgspec.Struct, frozen=True):
    """[security]: how the station's links are protected (common/config/security.py, docs/deployment.md)."""
    mode: SecurityMode = SecurityMode.INSECURE
    certs: str = ""  # certificate directory; "" = ~/.config/statehub/{station}/certs
    operators: list[str] = msgspec.field(default_factory=lambda: ["operator"])  # names of the operator role
    verify_names: bool = True  # a listener's certificate must name the host a process connects to


class ControllerConfig(msgspec.Struct, frozen=True):
    host: str
    name: str = "controller"
    command_rate_hz: Hz = 10.0
    tick_rate_hz: Hz = 20.0
    db: str = "var/controller.sqlite"
    mirror_timeout_s: Seconds = 1.0
    stale_after_s: Seconds = 0.5
    execution: Execution = DEFAULT_EXECUTION  # the order plans run in, unless the timed check needs a stricter one
    listen: list[str] | None = None
    connect: list[str] | None = None
    recording: RecordingConfig = RecordingConfig()


class DeviceConfig(msgspec.Struct, frozen=True):
    resource: str  # the table name: the resource in the station model
    type: str
    mode: DeviceMode = DeviceMode.EMULATE
    params: dict[str, Any] = msgspec.field(default_factory=dict)  # the driver parameters
    line: int = 0  # where it is declared, for later error messages
    delay: Duration | None = None  # how long one of its effects takes, when hubs.toml says so


def parse_delay(value: object) -> Duration:
    """A device's `delay`: seconds (fixed) or a `[min, max]` pair. Raises ValueError saying what is wrong."""
    def seconds(item: object) -> float:
        if isinstance(item, bool) or not isinstance(item, int | float):
            raise ValueError(f"expected seconds, a number, found {toml_type(item)} {item!r}")
        return float(item)

    if isinstance(value, list):
        if len(value) != 2:
            raise ValueError(f"an interval is [min, max], two numbers: found {len(value)} item(s) {value!r}")
        low, high = seconds(value[0]), seconds(value[1])
    else:
        try:
            low = high = seconds(value)
        except ValueError:
            raise ValueError(f"expected seconds (a number) or an interval [min, max], found {toml_type(value)} "
                             f"{value!r}") from None
    return Duration(low, high)


class HubConfig(msgspec.Struct, frozen=True):
    name: str  # the table name
    host: str
    ssh_user: str = "pi"
    rate_hz: Hz = 50.0
    command_timeout_s: Seconds = 1.0
    listen: list[str] | None = None
    connect: list[str] | None = None
    devices: dict[str, DeviceConfig] = msgspec.field(default_factory=dict)
    line: int = 0


class StationConfig(msgspec.Struct, frozen=True):
    path: str
    station: StationSection
    network: NetworkConfig
    controller: ControllerConfig
    hubs: dict[str, HubConfig]
    security: SecurityConfig = SecurityConfig()
    production: ProductionConfig = ProductionConfig()
    overview: OverviewConfig = OverviewConfig()

    @property
    def keys(self) -> Keys:
        """The station's key expressions."""
        return station_keys(self.station.name)

    @property
    def resources(self) -> dict[str, HubConfig]:
        """Each resource name and the hub that serves it."""
        return {r: hub for hub in self.hubs.values() for r in hub.devices}

    def hub_of(self, resource: str) -> HubConfig:
        try:
            return self.resources[resource]
        except KeyError:
            raise KeyError(f"{self.path}: no hub serves resource {resource!r}") from None

    def device(self, resource: str) -> DeviceConfig:
        return self.hub_of(resource).devices[resource]

    @property
    def delays(self) -> dict[str, Duration]:
        """resource -> the `delay` its device table gives (devices without one are left out)."""
        return {r: d.delay for hub in self.hubs.values() for r, d in hub.devices.items() if d.delay is not None}

    def network_for(self, process: str) -> NetworkConfig:
        """The network settings of "controller" or of a hub (its listen/connect override [network])."""
        section: ControllerConfig | HubConfig
        if process == "controller":
            section = self.controller
        elif process in self.hubs:
            section = self.hubs[process]
        else:
            raise KeyError(f"{self.path}: no hub named {process!r} (hubs: {', '.join(self.hubs)})")
        return NetworkConfig(
            mode=self.network.mode,
            listen=list(section.listen) if section.listen is not None else list(self.network.listen),
            connect=list(section.connect) if section.connect is not None else list(self.network.connect),
            lease_ms=self.network.lease_ms, max_message_bytes=self.network.max_message_bytes,
        )

    def loopback_network(self, process: str, port: int = 7447) -> NetworkConfig:
        """The network settings for running the whole station on one machine (virtual
        commissioning): peer mode, the controller listens on 127.0.0.1:`port`, every hub
        connects to it and listens on a port of its own, because peers do not route for
        each other: emulated devices that follow another hub's state are reached directly
        (gossip tells the peers where). The lease of the file is kept."""
        if process != "controller" and process not in self.hubs:
            raise KeyError(f"{self.path}: no hub named {process!r} (hubs: {', '.join(self.hubs)})")
        endpoint = f"tcp/127.0.0.1:{port}"
        controller = process == "controller"
        return NetworkConfig(mode=NetworkMode.PEER, listen=[endpoint] if controller else ["tcp/127.0.0.1:0"],
                             connect=[] if controller else [endpoint], lease_ms=self.network.lease_ms,
                             max_message_bytes=self.network.max_message_bytes)

    def load_model(self) -> Model:
        """Import the station model named by [station] model; errors name the file and line."""
        try:
            return load_model(self.station.model)
        except ModelLoadError as exc:
            lines = KeyLines(Path(self.path).read_text(encoding="utf-8")) if Path(self.path).is_file() else None
            line = lines.line_of(("station", "model")) if lines else None
            raise ConfigError([ConfigProblem(self.path, line, "station.model", str(exc))]) from exc


# --- loading -------------------------------------------------------------------------------

S = TypeVar("S", bound=msgspec.Struct)


class _Checker:
    """Collects problems while converting the TOML tables into the typed config."""

    def __init__(self, file: str, text: str) -> None:
        self.file = file
        self.lines = KeyLines(text)
        self.problems: list[ConfigProblem] = []

    def problem(self, path: tuple[str, ...], message: str) -> None:
        self.problems.append(ConfigProblem(self.file, self.lines.line_of(path), ".".join(path), message))

    def where(self, path: tuple[str, ...], host: str, ssh_user: str | None = None) -> None:
        """`host` and `ssh_user` reach the ssh command line of a deploy: only names, never options."""
        for key, problem in (("host", host_problem(host)), ("ssh_user", ssh_user and user_problem(ssh_user))):
            if problem:
                self.problem((*path, key), problem)

    def table(self, value: object, path: tuple[str, ...]) -> dict[str, Any] | None:
        if isinstance(value, dict):
            return value
        self.problem(path, f"must be a table, not {toml_type(value)}")
        return None

    def section(self, cls: type[S], table: Mapping[str, Any], path: tuple[str, ...], *,
                extra: Mapping[str, Any] | None = None, free: bool = False, skip: Iterable[str] = ()) -> S | None:
        """Convert `table` into `cls` field by field, so that every bad key is reported.
        `extra`: fields not read from the table; `free`: unknown keys are returned as `params`;
        `skip`: keys handled by the caller."""
        fields = {f.name: f for f in msgspec.structs.fields(cls)}
        extra = extra or {}
        values: dict[str, Any] = dict(extra)
        params: dict[str, Any] = {}
        ok = True
        skip = set(skip)
        for key, value in table.items():
            if key in skip:
                continue
            field = fields.get(key)
            if field is None or key in extra or key in ("params", "line"):
                if free:
                    params[key] = value
                    continue
                known = sorted(n for n in fields if n not in extra and n not in ("params", "line")) + sorted(skip)
                self.problem((*path, key), f"unknown key (known keys: {', '.join(known)})")
                ok = False
                continue
            try:
                values[key] = msgspec.convert(value, field.type)
            except msgspec.ValidationError as exc:
                self.problem((*path, key), _explain_type(exc, value, field.type, key))
                ok = False
        for name, field in fields.items():
            if field.required and name not in values:
                self.problem(path, f"missing key {name!r}")
                ok = False
        if free:
            values["params"] = params
        if "line" in fields:
            values["line"] = self.lines.line_of(path) or 0
        return cls(**values) if ok else None


def _explain_type(exc: msgspec.ValidationError, value: object, ftype: object, key: str) -> str:
    if isinstance(ftype, type) and issubclass(ftype, enum.StrEnum) and isinstance(value, str):
        return f"unknown {key} {value!r} (expected one of: {', '.join(words(ftype))})"
    text = re.sub(r"\s*- at `\$[^`]*`", "", str(exc))
    return f"{text} (found {toml_type(value)} {value!r})"


def load_config(path: str | Path, *, model: Model | None = None) -> StationConfig:
    """Read and check a deployment file; with `model`, also check it against the station model.
    Raises ConfigError (every problem, each with file, line and key) or OSError."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    return parse_config(text, str(path), model=model)


def parse_config(text: str, file: str = "hubs.toml", *, model: Model | None = None) -> StationConfig:
    checker = _Checker(file, text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([toml_problem(file, str(exc))]) from None

    for key in data:
        if key not in ("station", "network", "controller", "hubs", "security", "production", "overview"):
            checker.problem((key,), "unknown section (known: station, network, controller, hubs, security, "
                                    "production, overview)")

    station = network = controller = None
    table = checker.table(data.get("station"), ("station",)) if "station" in data else None
    if "station" not in data:
        checker.problems.append(ConfigProblem(file, None, "station", "missing section [station]"))
    elif table is not None:
        station = checker.section(StationSection, table, ("station",))
        if station is not None:
            if not _NAME.match(station.name):
                checker.problem(("station", "name"), f"{station.name!r} cannot be a key chunk "
                                                     f"(letters, digits, _ . - only)")
            if ":" not in station.model:
                checker.problem(("station", "model"), f"{station.model!r} must be 'module:attribute' "
                                                      f"or 'file.py:attribute'")
            elif is_file_reference(station.model):
                station = msgspec.structs.replace(
                    station, model=resolve_model_reference(station.model, Path(file).resolve().parent))

    table = checker.table(data.get("network", {}), ("network",))
    if table is not None:
        network = checker.section(NetworkConfig, table, ("network",))
        if network is not None and network.mode == NetworkMode.CLIENT and network.listen:
            checker.problem(("network", "listen"), "a zenoh client cannot listen: remove it or use mode 'peer'")

    if "controller" not in data:
        checker.problems.append(ConfigProblem(file, None, "controller", "missing section [controller]"))
    else:
        table = checker.table(data["controller"], ("controller",))
        if table is not None:
            controller = _load_controller(checker, table)
            if controller is not None:
                checker.where(("controller",), controller.host)

    hubs: dict[str, HubConfig] = {}
    served: dict[str, str] = {}
    hubs_table = checker.table(data.get("hubs", {}), ("hubs",))
    if not hubs_table:
        checker.problem(("hubs",), "no hubs: declare at least one [hubs.NAME] table")
    for hub_name, hub_value in (hubs_table or {}).items():
        hub = _load_hub(checker, hub_name, hub_value, served)
        if hub is not None:
            hubs[hub_name] = hub

    security = _load_security(checker, data.get("security", {}), controller, hubs)
    production = _load_production(checker, data.get("production", {}), text)
    overview = _load_overview(checker, data.get("overview", {}), controller, hubs, security)
    if checker.problems:
        raise ConfigError(checker.problems)
    assert station is not None and network is not None and controller is not None and security is not None
    assert production is not None and overview is not None
    config = StationConfig(path=file, station=station, network=network, controller=controller, hubs=hubs,
                           security=security, production=production, overview=overview)
    if model is not None:
        check_against_model(config, model, text=text)
    return config


def _load_controller(checker: _Checker, table: dict[str, Any]) -> ControllerConfig | None:
    path = ("controller", "recording")
    recording_table = checker.table(table.get("recording", {}), path)
    recording = None if recording_table is None else checker.section(RecordingConfig, recording_table, path)
    controller = checker.section(ControllerConfig, table, ("controller",), extra={"recording": recording},
                                 skip=("recording",))
    return controller if recording is not None else None


def _load_hub(checker: _Checker, name: str, value: object, served: dict[str, str]) -> HubConfig | None:
    path = ("hubs", name)
    table = checker.table(value, path)
    if table is None:
        return None
    if not _NAME.match(name):
        checker.problem(path, f"hub name {name!r} cannot be a key chunk (letters, digits, _ . - only)")
    devices: dict[str, DeviceConfig] = {}
    devices_table = checker.table(table.get("devices", {}), (*path, "devices"))
    for resource, device_value in (devices_table or {}).items():
        dpath = (*path, "devices", resource)
        device_table = checker.table(device_value, dpath)
        if device_table is None:
            continue
        if not _NAME.match(resource) or "." in resource:
            checker.problem(dpath, f"resource name {resource!r} cannot be a key chunk (letters, digits, _ - only)")
        if resource in served:
            checker.problem(dpath, f"resource {resource!r} is already served by hub {served[resource]!r}: "
                                   f"a resource belongs to exactly one hub")
        else:
            served[resource] = name
        delay = None
        if "delay" in device_table:
            try:
                delay = parse_delay(device_table["delay"])
            except ValueError as exc:
                checker.problem((*dpath, "delay"), str(exc))
        device = checker.section(DeviceConfig, device_table, dpath, extra={"resource": resource, "delay": delay},
                                 free=True, skip=("delay",))
        if device is not None:
            devices[resource] = device
    hub = checker.section(HubConfig, table, path, extra={"name": name, "devices": devices}, skip=("devices",))
    if hub is not None:
        checker.where(path, hub.host, hub.ssh_user)
    return hub


def _load_security(checker: _Checker, value: object, controller: ControllerConfig | None,
                   hubs: Mapping[str, HubConfig]) -> SecurityConfig | None:
    """[security]; a certificate's common name is the name of its holder, so no two may share one."""
    table = checker.table(value, ("security",))
    security = checker.section(SecurityConfig, table, ("security",)) if table is not None else None
    if security is None:
        return None
    taken = {hub: "a hub" for hub in hubs} | ({controller.name: "the controller"} if controller else {})
    for name in security.operators:
        if not _NAME.match(name) or name in taken:
            why = f"is already the name of {taken[name]}" if name in taken else "must be letters, digits, _ . -"
            checker.problem(("security", "operators"), f"operator {name!r} {why} (a certificate's common name "
                                                       f"must name one holder)")
    if controller and controller.name in hubs:
        checker.problem(("controller", "name"), f"{controller.name!r} is also a hub's name: certificates name "
                                                f"their holder, so the controller needs a name of its own")
    return security


def _load_overview(checker: _Checker, value: object, controller: ControllerConfig | None,
                   hubs: Mapping[str, HubConfig], security: SecurityConfig | None) -> OverviewConfig | None:
    """[overview]: its bind address, and a certificate name no other holder has (it gets the viewer role)."""
    table = checker.table(value, ("overview",))
    overview = checker.section(OverviewConfig, table, ("overview",)) if table is not None else None
    if overview is None:
        return None
    try:
        parse_bind(overview.bind)
    except ValueError as exc:
        checker.problem(("overview", "bind"), str(exc))
    taken = {hub: "a hub" for hub in hubs} | ({controller.name: "the controller"} if controller else {})
    taken |= {name: "an operator" for name in (security.operators if security else ())}
    if not _NAME.match(overview.name) or overview.name in taken:
        why = (f"is already the name of {taken[overview.name]}" if overview.name in taken
               else "must be letters, digits, _ . -")
        checker.problem(("overview", "name"), f"{overview.name!r} {why} (a certificate's common name must name one "
                                              f"holder)")
    return overview


def _load_production(checker: _Checker, value: object, text: str) -> ProductionConfig | None:
    """[production] (common/config/production.py); an order table's problems name its index and line."""
    table = checker.table(value, ("production",))
    if table is None:
        return None
    entries: list[OrderEntry] = []
    orders = table.get("orders", [])
    lines = order_table_lines(text)
    ok = True
    if not isinstance(orders, list):
        checker.problem(("production", "orders"), f"must be an array of tables, not {toml_type(orders)}")
        orders, ok = [], False
    for i, entry in enumerate(orders):
        key = f"production.orders[{i}]"
        line = lines[i] if i < len(lines) else checker.lines.line_of(("production", "orders"))
        try:
            entries.append(msgspec.convert(entry, OrderEntry))
        except msgspec.ValidationError as exc:
            checker.problems.append(ConfigProblem(checker.file, line, key, re.sub(r"\s*- at `\$[^`]*`", "",
                                                                                  str(exc))))
            ok = False
    production = checker.section(ProductionConfig, table, ("production",), extra={"orders": entries},
                                 skip=("orders",))
    if production is None or not ok:
        return None
    for path, message in config_problems(production):
        _production_problem(checker, path, message, lines)
    return production


def _production_problem(checker: _Checker, path: tuple[str, ...], message: str, order_lines: list[int]) -> None:
    """A problem of [production]; `orders[i]` in `path` is the i-th order table."""
    index = re.fullmatch(r"orders\[(\d+)\]", path[1]) if len(path) > 1 else None
    if index is None:
        checker.problem(path, message)
        return
    i = int(index.group(1))
    line = order_lines[i] if i < len(order_lines) else checker.lines.line_of(("production", "orders"))
    checker.problems.append(ConfigProblem(checker.file, line, ".".join(path), message))


# --- the station model ----------------------------------------------------------------------

def _check_type(checker: _Checker, hub: str, resource: str, device_type: str, model: Model) -> None:
    model_resource = model.resource_by_name.get(resource)
    if model_resource is None or not model_resource.device_type or model_resource.device_type == device_type:
        return
    # A type that is neither built in nor the model's is most likely misspelt: say both.
    unknown = "unknown device " if device_type not in DEVICE_TYPES else ""
    checker.problem(("hubs", hub, "devices", resource, "type"),
                    f"{unknown}type {device_type!r}, but resource {resource!r} of the model is a "
                    f"{model_resource.device_type!r}")


def check_against_model(config: StationConfig, model: Model, *, text: str | None = None) -> None:
    """Every device is a resource of the model with the same type, and every resource has a hub."""
    if text is None:
        text = Path(config.path).read_text(encoding="utf-8") if Path(config.path).is_file() else ""
    checker = _Checker(config.path, text)
    by_name = model.resource_by_name
    for hub in config.hubs.values():
        for resource, device in hub.devices.items():
            if resource not in by_name:
                checker.problem(("hubs", hub.name, "devices", resource),
                                f"resource {resource!r} is not in station model {model.name!r} "
                                f"(its resources: {', '.join(sorted(by_name))})")
            else:
                _check_type(checker, hub.name, resource, device.type, model)
    for resource in by_name:
        if resource not in config.resources:
            checker.problem(("station", "model"), f"resource {resource!r} of station model {model.name!r} "
                                                  f"is served by no hub")
    for path, message in model_problems(config.production, model):
        _production_problem(checker, path, message, order_table_lines(text))
    if checker.problems:
        raise ConfigError(checker.problems)


def _type_problems_of_broken_file(text: str, file: str) -> list[ConfigProblem]:
    """The device types that differ from the model's, in a file with other problems.

    A device type is free text (a station brings its own), so a misspelt one is only
    caught against the model; reporting it with the file's other problems keeps to
    "every problem at once". Best effort: nothing if the model cannot be found or built."""
    try:
        data = tomllib.loads(text)
        model = load_model(resolve_model_reference(str(data["station"]["model"]), Path(file).resolve().parent))
        hubs = data.get("hubs", {})
    except Exception:  # any failure here is already reported, or will be once the file is fixed
        return []
    if not isinstance(hubs, dict):
        return []
    checker = _Checker(file, text)
    for hub, table in hubs.items():
        devices = table.get("devices", {}) if isinstance(table, dict) else {}
        for resource, device in (devices if isinstance(devices, dict) else {}).items():
            if isinstance(device, dict) and isinstance(device.get("type"), str):
                _check_type(checker, hub, resource, device["type"], model)
    return checker.problems


def load_station(path: str | Path) -> tuple[StationConfig, Model]:
    """Load the deployment file and the station model it names, and check them against each other."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        config = parse_config(text, str(path))
    except ConfigError as error:
        problems = error.problems + _type_problems_of_broken_file(text, str(path))
        raise ConfigError(problems) from None
    model = config.load_model()
    check_against_model(config, model, text=text)
    return config, model
