"""Wire messages: msgspec structs derived from each resource's model, encoded as MessagePack.

Per resource (`Codec(resource)`), two struct types built at runtime:

    Command  controller -> hub   {schema, model_hash, <command vars>, seq, controller, epoch, time}
    State    hub -> controller   {schema, model_hash, <measured vars>, mirror, status, detail,
                                  seq, time, hub}

Variables are keyed by their short name (`run_c`), as drivers use them; values use
the model's domains (bool, enumeration name, small int). A measured value may be
None: unknown (device lost, not read yet). `mirror` is the last command the hub
applied, as it received it (seq included), or None before the first one. `epoch`: the
controller's hold on the station (common/wire/holder_token.py); a hub orders `seq` per (controller, epoch).

Every payload has a size limit computed from its struct (`Codec.max_command_bytes`,
`max_state_bytes`, common/wire/bounds.py): a longer payload is refused (`OversizedPayload`)
before anything is decoded. Names are bounded (`MAX_NAME_CHARS`), and so is `detail`.

Every payload carries `schema` (the layout version of this module, `SCHEMA`) and
`model_hash` (`model_hash(resource)`: a stable hash of the resource's name and of
its command and measured variables and their domains). A hub and a controller
built from different models refuse each other's messages with a `ModelMismatch`
naming the resource and both hashes.

Decoding never raises anything but `MessageError` (or a subclass):
`SchemaMismatch`, `ModelMismatch`, `DomainError` (a value outside its variable's
domain: hubs reject such commands and say so in their status) or plain
`MessageError` (not MessagePack, missing or mistyped field). The fast path is one
typed msgspec decode; only a failing payload is looked at again to explain why.

Code that handles a resource's messages without knowing its variables reads their header
through `CommandMessage` and `StateMessage` (protocols every generated struct satisfies) and
their variables through `Codec.values`.

`Message`, `encode` and `decode` cover the plain structs of `{station}/ctl/...`.
"""

from __future__ import annotations

import enum
import hashlib
import json
import time as _time
from collections.abc import Iterable, Mapping
from typing import Annotated, Any, Literal, Protocol, TypeVar, cast, overload, runtime_checkable

import msgspec

from common.model import Domain, Kind, Resource, Value, Variable
from common.wire.bounds import max_encoded_size

SCHEMA = 2  # bump on any change of the envelope layout below or of HubStatus

COMMAND_ENVELOPE = ("schema", "model_hash", "seq", "controller", "epoch", "time")
STATE_ENVELOPE = ("schema", "model_hash", "mirror", "status", "detail", "seq", "time", "hub")
RESERVED_NAMES = frozenset(COMMAND_ENVELOPE + STATE_ENVELOPE)
MAX_NAME_CHARS = 128  # a controller id or a hub name on the wire
MAX_DETAIL_CHARS = 500  # a state's `detail`: hubs cut theirs to this
Name = Annotated[str, msgspec.Meta(max_length=MAX_NAME_CHARS)]
Count = Annotated[int, msgspec.Meta(ge=0)]
Hash = Annotated[str, msgspec.Meta(max_length=64)]  # ours are 16 hex digits; longer ones are refused


class HubStatus(enum.StrEnum):
    """What a hub says about one resource, in every state message."""

    OK = "ok"  # device answers, the newest command is applied
    NO_COMMAND = "no_command"  # no command received since the hub started: outputs in safe state
    SAFE_STATE = "safe_state"  # commands stopped arriving (command timeout): outputs in safe state
    DEVICE_LOST = "device_lost"  # the device does not answer: measured values are None
    REJECTED = "rejected"  # the newest command was refused (out of domain, other model): `detail` says why
    ERROR = "error"  # the driver failed to apply the command: `detail` says why


# --- the header of every resource's messages -------------------------------------------------
# The structs are built per resource at runtime (`Codec`), with the header fields around the
# variables in wire order (schema, model_hash, <variables>, seq, ...): a base Struct holding the
# header would put its fields first and change the bytes on the wire. So the header is a protocol.

@runtime_checkable
class CommandMessage(Protocol):
    """The header of a command (`Codec.Command`), whatever its resource: its variables are `Codec.values`."""

    @property
    def schema(self) -> int: ...
    @property
    def model_hash(self) -> str: ...
    @property
    def seq(self) -> int: ...  # ordered per (controller, epoch)
    @property
    def controller(self) -> str: ...  # the sender's id
    @property
    def epoch(self) -> int: ...  # the sender's hold on the station (common/wire/holder_token.py); 0: none persisted
    @property
    def time(self) -> float: ...  # when it was sent (wall clock)


@runtime_checkable
class StateMessage(Protocol):
    """The header of a state (`Codec.State`), whatever its resource: its measured values are `Codec.values`."""

    @property
    def schema(self) -> int: ...
    @property
    def model_hash(self) -> str: ...
    @property
    def mirror(self) -> CommandMessage | None: ...  # the last command the hub applied, as received
    @property
    def status(self) -> HubStatus: ...
    @property
    def detail(self) -> str: ...  # why, when the status is not ok
    @property
    def seq(self) -> int: ...  # the hub's own count of the states it published
    @property
    def time(self) -> float: ...  # when it was published (wall clock)
    @property
    def hub(self) -> str: ...


class MessageKind(enum.StrEnum):
    """Which of a resource's two messages a payload is meant to be (the word names it in errors)."""

    COMMAND = "command"
    STATE = "state"


# --- errors ------------------------------------------------------------------------------

class MessageError(ValueError):
    """A payload that cannot be used. Log it with its key and drop it."""

    def __init__(self, message: str, *, resource: str | None = None) -> None:
        self.resource = resource
        super().__init__(message)


class OversizedPayload(MessageError):
    """A payload longer than any valid message of its key: refused before it is decoded."""


class SchemaMismatch(MessageError):
    def __init__(self, message: str, *, resource: str | None, local: int, remote: object) -> None:
        self.local, self.remote = local, remote
        super().__init__(message, resource=resource)


class ModelMismatch(MessageError):
    def __init__(self, message: str, *, resource: str, local: str, remote: object) -> None:
        self.local, self.remote = local, remote
        super().__init__(message, resource=resource)


class DomainError(MessageError):
    """A value outside its variable's domain. `seq`/`controller`: of the offending command, when readable."""

    def __init__(self, message: str, *, resource: str, variable: str, value: object, domain: str,
                 seq: int | None = None, controller: str | None = None) -> None:
        self.variable, self.value, self.domain = variable, value, domain
        self.seq, self.controller = seq, controller
        super().__init__(message, resource=resource)


# --- model hash and field types ---------------------------------------------------------------

def wire_variables(resource: Resource) -> tuple[Variable, ...]:
    """The variables that travel on the wire: commands and measurements (estimates stay in the controller)."""
    return tuple(v for v in resource.variables if v.kind in (Kind.COMMAND, Kind.MEASURED))


def model_hash(resource: Resource) -> str:
    """A stable hash of what both ends must agree on: the resource name, and each wire variable's
    short name, kind and domain (values in declared order; bools stay distinct from ints)."""
    described = sorted([v.name, v.kind.value, list(v.domain.values)] for v in wire_variables(resource))
    text = json.dumps({"resource": resource.name, "variables": described}, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _field_type(domain: Domain) -> tuple[Any, bool]:
    """The msgspec type that checks `domain` while decoding, and whether that check is complete."""
    values = domain.values
    if domain.is_bool:
        return bool, True
    ints = sorted(v for v in values if isinstance(v, int) and not isinstance(v, bool))
    if ints and len(ints) == len(values):
        if ints == list(range(ints[0], ints[-1] + 1)):
            return Annotated[int, msgspec.Meta(ge=ints[0], le=ints[-1])], True
        return Literal[tuple(values)], True
    if all(isinstance(v, str) for v in values):
        return Literal[tuple(values)], True
    # A mixed domain (not built by Domain.enum/range): decode loosely, check by hand.
    longest = max((len(v) for v in values if isinstance(v, str)), default=0)
    return bool | int | Annotated[str, msgspec.Meta(max_length=longest)], False


def _format(value: object) -> str:
    """A received value for an error message, cut short (it may be anything)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _format_hash(value: object) -> str:
    if isinstance(value, str) and len(value) <= 64 and value.isalnum():
        return value
    return _format(value)


# --- the per-resource codec -------------------------------------------------------------------

class CommandSender(msgspec.Struct, frozen=True):
    """The identity fields of a command, read without the rest (a map's other keys are skipped)."""

    controller: Name
    epoch: Count = 0
    seq: Count = 0


_sender_decoder = msgspec.msgpack.Decoder(CommandSender)


class Codec:
    """Command and state structs of one resource, and their encoding.

    Build messages with `command(...)` / `state(...)` (they check domains and fill in
    schema, model_hash and time); send `encode_*`; receive `decode_*`.
    """

    def __init__(self, resource: Resource) -> None:
        self.resource = resource.name
        self.model_hash = model_hash(resource)
        self.commands: tuple[Variable, ...] = resource.commands
        self.measured: tuple[Variable, ...] = resource.measured
        self._by_name = {v.name: v for v in (*self.commands, *self.measured)}
        for v in self._by_name.values():
            if v.name in RESERVED_NAMES:
                raise ValueError(f"resource {self.resource}: variable {v.path} uses the reserved message "
                                 f"field name {v.name!r}")
        base = "".join(part.capitalize() for part in self.resource.replace("-", "_").split("_")) or "Resource"

        cmd_fields: list[tuple[str, Any] | tuple[str, Any, Any]] = [("schema", int), ("model_hash", Hash)]
        # Variables whose domain msgspec cannot check by itself (mixed domains): checked by hand.
        self._unchecked_commands: list[Variable] = []
        self._unchecked_measured: list[Variable] = []
        for v in self.commands:
            ftype, complete = _field_type(v.domain)
            cmd_fields.append((v.name, ftype))
            if not complete:
                self._unchecked_commands.append(v)
        cmd_fields += [("seq", Count), ("controller", Name), ("epoch", Count, 0), ("time", float)]
        self.Command: type[msgspec.Struct] = msgspec.defstruct(
            f"{base}Command", cmd_fields, kw_only=True, frozen=True, module=__name__)

        state_fields: list[tuple[str, Any] | tuple[str, Any, Any]] = [("schema", int), ("model_hash", Hash)]
        for v in self.measured:
            ftype, complete = _field_type(v.domain)
            state_fields.append((v.name, ftype | None))
            if not complete:
                self._unchecked_measured.append(v)
        state_fields += [("mirror", self.Command | None), ("status", HubStatus),
                         ("detail", Annotated[str, msgspec.Meta(max_length=MAX_DETAIL_CHARS)], ""),
                         ("seq", Count), ("time", float), ("hub", Name)]
        self.State: type[msgspec.Struct] = msgspec.defstruct(
            f"{base}State", state_fields, kw_only=True, frozen=True, module=__name__)

        self._encoder = msgspec.msgpack.Encoder()
        self._command_decoder = msgspec.msgpack.Decoder(self.Command)
        self._state_decoder = msgspec.msgpack.Decoder(self.State)
        self.max_command_bytes = max_encoded_size(self.Command)
        self.max_state_bytes = max_encoded_size(self.State)

    def __repr__(self) -> str:
        return f"Codec({self.resource}, hash={self.model_hash})"

    # -- building ------------------------------------------------------------------------
    def _short(self, key: str) -> str:
        prefix = f"{self.resource}."
        return key[len(prefix):] if key.startswith(prefix) else key

    def _check_value(self, var: Variable, value: object, *, seq: object = None, controller: object = None,
                     where: str = "") -> None:
        # type() first: Domain accepts 2.0 for 2, but only bools, ints and names travel.
        if type(value) not in (bool, int, str) or value not in var.domain:
            raise DomainError(
                f"resource {self.resource}: {var.path}{where} = {_format(value)} is outside its domain "
                f"{var.domain.describe()}",
                resource=self.resource, variable=var.path, value=value, domain=var.domain.describe(),
                seq=seq if isinstance(seq, int) and not isinstance(seq, bool) else None,
                controller=controller if isinstance(controller, str) else None)

    def _values(self, values: Mapping[str, Value | None], variables: tuple[Variable, ...],
                what: str) -> dict[str, Value | None]:
        result: dict[str, Value | None] = {}
        names = {v.name for v in variables}
        for key, value in values.items():
            name = self._short(key)
            if name not in names:
                raise MessageError(f"resource {self.resource} has no {what} variable {key!r} "
                                   f"(its {what} variables: {', '.join(sorted(names)) or 'none'})",
                                   resource=self.resource)
            result[name] = value
        return result

    def command(self, values: Mapping[str, Value], *, seq: int, controller: str, epoch: int = 0,
                time: float | None = None) -> CommandMessage:
        """A command with every command variable (keyed `run_c` or `nr.run_c`); checks the domains.
        `epoch` 0: a sender without a persisted hold on the station (a test, `hubctl modeltest`)."""
        given = self._values(values, self.commands, "command")
        missing = [v.path for v in self.commands if v.name not in given]
        if missing:
            raise MessageError(f"resource {self.resource}: command lacks {', '.join(missing)}",
                               resource=self.resource)
        for v in self.commands:
            self._check_value(v, given[v.name], seq=seq, controller=controller)
        return cast(CommandMessage, self.Command(
            schema=SCHEMA, model_hash=self.model_hash, seq=seq, controller=controller, epoch=epoch,
            time=_time.time() if time is None else time, **given))

    def state(self, values: Mapping[str, Value | None], *, status: HubStatus, seq: int, hub: str,
              mirror: CommandMessage | None = None, detail: str = "", time: float | None = None) -> StateMessage:
        """A state message; a measured variable left out (or None) is unknown. Checks the domains."""
        given = self._values(values, self.measured, "measured")
        for v in self.measured:
            if given.get(v.name) is not None:
                self._check_value(v, given[v.name])
        measured = {v.name: given.get(v.name) for v in self.measured}
        if mirror is not None and not isinstance(mirror, self.Command):
            raise MessageError(f"resource {self.resource}: mirror must be a {self.Command.__name__}, "
                               f"not {type(mirror).__name__}", resource=self.resource)
        # HubStatus(): a status given as its word is stored as the member a decoded state would hold.
        return cast(StateMessage, self.State(
            schema=SCHEMA, model_hash=self.model_hash, mirror=mirror, status=HubStatus(status), detail=detail,
            seq=seq, hub=hub, time=_time.time() if time is None else time, **measured))

    @overload
    def values(self, message: CommandMessage, *, paths: bool = False) -> dict[str, Value]: ...
    @overload
    def values(self, message: StateMessage, *, paths: bool = False) -> dict[str, Value | None]: ...

    def values(self, message: CommandMessage | StateMessage, *, paths: bool = False) -> Mapping[str, Value | None]:
        """The variables of a command (command vars, every one known) or a state (measured vars,
        None = unknown), keyed by short name, or by path (`nr.run_c`) with `paths=True`."""
        variables = self.commands if isinstance(message, self.Command) else self.measured
        if not isinstance(message, self.Command | self.State):
            raise TypeError(f"not a message of resource {self.resource}: {type(message).__name__}")
        return {(v.path if paths else v.name): getattr(message, v.name) for v in variables}

    # -- encoding ------------------------------------------------------------------------
    def encode_command(self, command: CommandMessage) -> bytes:
        return self._encoder.encode(command)

    def encode_state(self, state: StateMessage) -> bytes:
        return self._encoder.encode(state)

    def decode_command(self, data: bytes | bytearray | memoryview) -> CommandMessage:
        """The Command in `data`; raises MessageError (DomainError: a value out of its domain)."""
        self._check_size(data, self.max_command_bytes, MessageKind.COMMAND)
        try:
            command = cast(CommandMessage, self._command_decoder.decode(data))
        except Exception:
            raise self._explain(data, MessageKind.COMMAND) from None
        self._check_envelope(command, "command")
        if self._unchecked_commands:
            self._check_unchecked(command, self._unchecked_commands, "")
        return command

    def decode_state(self, data: bytes | bytearray | memoryview) -> StateMessage:
        """The State in `data`; raises MessageError."""
        self._check_size(data, self.max_state_bytes, MessageKind.STATE)
        try:
            state = cast(StateMessage, self._state_decoder.decode(data))
        except Exception:
            raise self._explain(data, MessageKind.STATE) from None
        self._check_envelope(state, "state")
        if state.mirror is not None:
            self._check_envelope(state.mirror, "state (mirror)")
        if self._unchecked_measured:
            self._check_unchecked(state, self._unchecked_measured, "")
        if self._unchecked_commands and state.mirror is not None:
            self._check_unchecked(state.mirror, self._unchecked_commands, " (mirror)")
        return state

    def sender(self, data: bytes | bytearray | memoryview) -> CommandSender:
        """Who claims to have sent the command in `data` (size-checked, nothing else decoded):
        a hub refuses a command of anyone but the station's holder before decoding it."""
        self._check_size(data, self.max_command_bytes, MessageKind.COMMAND)
        try:
            return _sender_decoder.decode(data)
        except Exception as exc:
            raise MessageError(f"resource {self.resource}: command has no readable sender ({exc})",
                               resource=self.resource) from None

    # -- checks and explanations -------------------------------------------------------------
    def _check_size(self, data: bytes | bytearray | memoryview, limit: int, what: MessageKind) -> None:
        if len(data) > limit:
            raise OversizedPayload(f"resource {self.resource}: {what} of {len(data)} bytes, more than any valid "
                                   f"{what} of this resource ({limit} bytes): not decoded", resource=self.resource)

    def _check_envelope(self, message: CommandMessage | StateMessage, what: str) -> None:
        if message.schema != SCHEMA:
            raise self._schema_error(what, message.schema)
        if message.model_hash != self.model_hash:
            raise self._model_error(what, message.model_hash)

    def _schema_error(self, what: str, remote: object) -> SchemaMismatch:
        return SchemaMismatch(
            f"resource {self.resource}: {what} has message schema {_format(remote)}, this build speaks "
            f"schema {SCHEMA}: update the older side", resource=self.resource, local=SCHEMA, remote=remote)

    def _model_error(self, what: str, remote: object) -> ModelMismatch:
        return ModelMismatch(
            f"resource {self.resource}: {what} comes from a different model (model hash {_format_hash(remote)}, "
            f"ours {self.model_hash}): hub and controller must run the same resource model",
            resource=self.resource, local=self.model_hash, remote=remote)

    def _check_unchecked(self, message: CommandMessage | StateMessage, variables: list[Variable],
                         where: str) -> None:
        for v in variables:
            value = getattr(message, v.name)
            if value is not None or v.kind is Kind.COMMAND:
                self._check_value(v, value, seq=getattr(message, "seq", None),
                                  controller=getattr(message, "controller", None), where=where)

    def _explain(self, data: bytes | bytearray | memoryview, what: MessageKind) -> MessageError:
        """Why a payload failed the typed decode, as precisely as it can be said."""
        try:
            return self._diagnose(data, what)
        except MessageError as exc:
            return exc
        except Exception as exc:  # never let a diagnosis bug escape as anything but MessageError
            return MessageError(f"resource {self.resource}: unreadable {what}: {type(exc).__name__}: {exc}",
                                resource=self.resource)

    def _diagnose(self, data: bytes | bytearray | memoryview, what: MessageKind) -> MessageError:
        prefix = f"resource {self.resource}: {what}"
        try:
            raw = msgspec.msgpack.decode(data)
        except Exception as exc:
            return MessageError(f"{prefix} is not MessagePack ({exc})", resource=self.resource)
        if not isinstance(raw, dict):
            return MessageError(f"{prefix} is a {type(raw).__name__}, not a map", resource=self.resource)
        if "schema" not in raw:
            return MessageError(f"{prefix} has no schema version", resource=self.resource)
        if raw["schema"] != SCHEMA or isinstance(raw["schema"], bool):
            return self._schema_error(what, raw["schema"])
        if raw.get("model_hash") != self.model_hash:
            if "model_hash" not in raw:
                return MessageError(f"{prefix} has no model_hash", resource=self.resource)
            return self._model_error(what, raw["model_hash"])
        if what is MessageKind.COMMAND and "hub" in raw and "status" in raw:
            return MessageError(f"{prefix}: this is a state message (it has `hub` and `status`)",
                                resource=self.resource)
        if what is MessageKind.STATE and "controller" in raw and "hub" not in raw:
            return MessageError(f"{prefix}: this is a command message (it has `controller`, no `hub`)",
                                resource=self.resource)
        variables = self.commands if what is MessageKind.COMMAND else self.measured
        self._diagnose_values(raw, variables, what, "")
        if what is MessageKind.STATE and isinstance(raw.get("mirror"), dict):
            mirror = raw["mirror"]
            if mirror.get("schema") != SCHEMA or isinstance(mirror.get("schema"), bool):
                return self._schema_error("state (mirror)", mirror.get("schema"))
            if mirror.get("model_hash") != self.model_hash:
                return self._model_error("state (mirror)", mirror.get("model_hash"))
            self._diagnose_values(mirror, self.commands, "state", " (mirror)")
        # The values are fine: say what msgspec says (it names the field, e.g. "at `$.seq`").
        try:
            msgspec.convert(raw, self.Command if what is MessageKind.COMMAND else self.State, strict=True)
        except msgspec.ValidationError as exc:
            return MessageError(f"{prefix}: {exc}", resource=self.resource)
        return MessageError(f"{prefix} is not a valid {what} message", resource=self.resource)

    def _diagnose_values(self, raw: dict[Any, Any], variables: tuple[Variable, ...], what: str, where: str) -> None:
        for v in variables:
            if v.name not in raw:
                raise MessageError(f"resource {self.resource}: {what}{where} lacks variable {v.path}",
                                   resource=self.resource)
            value = raw[v.name]
            if value is None and v.kind is Kind.MEASURED:
                continue
            self._check_value(v, value, seq=raw.get("seq"), controller=raw.get("controller"), where=where)


def codecs_for(resources: Iterable[Resource]) -> dict[str, Codec]:
    """A codec per resource, keyed by resource name (e.g. `codecs_for(model.resources)`)."""
    return {r.name: Codec(r) for r in resources}


# --- plain messages ({station}/ctl/..., self-test reports) ---------------------------------

class Message(msgspec.Struct, kw_only=True):
    """Base of plain wire structs: carries the schema version. Subclass it and add fields."""

    schema: int = SCHEMA


class _SchemaHeader(msgspec.Struct):
    schema: int


M = TypeVar("M", bound=msgspec.Struct)

_encoder = msgspec.msgpack.Encoder()
_decoders: dict[type, msgspec.msgpack.Decoder[Any]] = {}


def encode(message: msgspec.Struct) -> bytes:
    """MessagePack bytes of any msgspec struct (a `Message` carries its schema version)."""
    return _encoder.encode(message)


def decode(data: bytes | bytearray | memoryview, type_: type[M]) -> M:
    """Decode a struct of `type_`; raises MessageError only. A `Message` must carry our schema."""
    name = type_.__name__
    if issubclass(type_, Message):
        try:
            header = msgspec.msgpack.decode(data, type=_SchemaHeader)
        except Exception as exc:
            raise MessageError(f"{name}: no readable schema version ({exc})") from None
        if header.schema != SCHEMA:
            raise SchemaMismatch(f"{name} has message schema {header.schema}, this build speaks schema {SCHEMA}",
                                 resource=None, local=SCHEMA, remote=header.schema)
    decoder = _decoders.get(type_)
    if decoder is None:
        decoder = _decoders[type_] = msgspec.msgpack.Decoder(type_)
    try:
        return decoder.decode(data)
    except Exception as exc:
        raise MessageError(f"{name}: {exc}") from None
