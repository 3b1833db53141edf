"""Wire messages: round trips, domain checks, model/schema mismatches, and garbage that never escapes."""

from __future__ import annotations

import contextlib

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.model import Domain, Resource, Value, Variable, command, estimated, measured
from common.wire.messages import (
    COMMAND_ENVELOPE,
    SCHEMA,
    STATE_ENVELOPE,
    Codec,
    CommandMessage,
    DomainError,
    HubStatus,
    Message,
    MessageError,
    ModelMismatch,
    SchemaMismatch,
    StateMessage,
    codecs_for,
    decode,
    encode,
    model_hash,
)


def nutrunner(name: str = "nr") -> Resource:
    return Resource(name, (command(f"{name}.run_c", initial=False), measured(f"{name}.run_m"),
                           measured(f"{name}.tqr_m"), measured(f"{name}.fail_m")), device_type="nutrunner")


def robot(poses: tuple[str, ...] = ("home", "bolt1", "bolt2")) -> Resource:
    return Resource("ur", (
        command("ur.ref_pos_c", Domain.enum(*poses), "home"),
        command("ur.speed_c", Domain.range(1, 5), 1),
        measured("ur.pos_m", Domain.enum(*poses, "unknown")),
        measured("ur.prot_stop_m"),
        measured("ur.load_m", Domain.range(-2, 3)),
        estimated("ur.tool_e", Domain.enum("none", "nutrunner"), "none"),
    ))


def odd() -> Resource:
    """Domains the constructors never build: non-contiguous ints, mixed values."""
    return Resource("odd", (command("odd.level_c", Domain((1, 3, 5)), 1),
                            command("odd.mix_c", Domain((0, "auto")), 0),
                            measured("odd.mix_m", Domain((0, "auto")))))


RESOURCES = [nutrunner(), robot(), odd()]
CODECS = codecs_for(RESOURCES)


def values_of(variables: tuple[Variable, ...]) -> st.SearchStrategy[dict[str, Value]]:
    return st.fixed_dictionaries({v.name: st.sampled_from(v.domain.values) for v in variables})


def measured_of(variables: tuple[Variable, ...]) -> st.SearchStrategy[dict[str, Value | None]]:
    return st.fixed_dictionaries({v.name: st.none() | st.sampled_from(v.domain.values) for v in variables})


seqs = st.integers(min_value=0, max_value=2**63 - 1)
times = st.floats(allow_nan=False, allow_infinity=False)


def a_command(codec: Codec, seq: int = 1, **overrides: Value) -> CommandMessage:
    values = {v.name: v.initial for v in codec.commands} | overrides
    return codec.command(values, seq=seq, controller="decs")


# --- round trips --------------------------------------------------------------------------

@pytest.mark.parametrize("codec", CODECS.values(), ids=list(CODECS))
@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), seq=seqs, time=times)
def test_command_round_trip(codec: Codec, data: st.DataObject, seq: int, time: float) -> None:
    values = data.draw(values_of(codec.commands))
    cmd = codec.command(values, seq=seq, controller="decs", time=time)
    back = codec.decode_command(codec.encode_command(cmd))
    assert back == cmd
    assert codec.values(back) == values
    assert (back.seq, back.controller, back.time) == (seq, "decs", time)


@pytest.mark.parametrize("codec", CODECS.values(), ids=list(CODECS))
@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), seq=seqs, status=st.sampled_from(HubStatus), with_mirror=st.booleans())
def test_state_round_trip(codec: Codec, data: st.DataObject, seq: int, status: HubStatus, with_mirror: bool) -> None:
    values = data.draw(measured_of(codec.measured))
    mirror = codec.command(data.draw(values_of(codec.commands)), seq=seq, controller="decs") if with_mirror else None
    state = codec.state(values, status=status, seq=seq, hub="pi-tool", mirror=mirror, detail="x")
    back = codec.decode_state(codec.encode_state(state))
    assert back == state
    assert codec.values(back) == values
    assert back.mirror == mirror and back.status is status and back.hub == "pi-tool"


def test_values_by_path_and_unknown_measurements() -> None:
    codec = CODECS["nr"]
    cmd = codec.command({"nr.run_c": True}, seq=7, controller="decs")
    assert codec.values(cmd, paths=True) == {"nr.run_c": True}
    state = codec.state({"nr.run_m": True}, status=HubStatus.OK, seq=1, hub="pi-tool", mirror=cmd)
    assert codec.values(state) == {"run_m": True, "tqr_m": None, "fail_m": None}
    mirror = codec.decode_state(codec.encode_state(state)).mirror
    assert mirror is not None and mirror.seq == 7


def test_every_resource_of_the_reference_station_round_trips() -> None:
    stations = pytest.importorskip("common.stations.engine_assembly")
    model = stations.build_model()
    for name, codec in codecs_for(model.resources).items():
        cmd = a_command(codec, seq=3)
        state = codec.state({v.name: v.initial for v in codec.measured}, status=HubStatus.OK, seq=4, hub=name,
                            mirror=cmd)
        assert codec.decode_state(codec.encode_state(state)) == state
        assert codec.decode_command(codec.encode_command(cmd)) == cmd


# --- the wire format and the typed header --------------------------------------------------------
# Encoded by the build before the header became `CommandMessage`/`StateMessage` (a command of epoch 3,
# seq 7; a state in safe_state mirroring it): the bytes on the wire must not change.
RECORDED_WIRE = {
    "nr": ("87a6736368656d6102aa6d6f64656c5f68617368b032323133636530383561393733636234a572756e5f63c2a373657107aa"
           "636f6e74726f6c6c6572a464656373a565706f636803a474696d65cb41d954fc40100000",
           "8ba6736368656d6102aa6d6f64656c5f68617368b032323133636530383561393733636234a572756e5f6dc2a57471725f6d"
           "c2a66661696c5f6dc2a66d6972726f7287a6736368656d6102aa6d6f64656c5f68617368b03232313363653038356139373363"
           "6234a572756e5f63c2a373657107aa636f6e74726f6c6c6572a464656373a565706f636803a474696d65cb41d954fc40100000"
           "a6737461747573aa736166655f7374617465a664657461696cb76e6f20636f6d6d616e642077697468696e20312e302073a373"
           "657129a474696d65cb41d954fc40600000a3687562a770692d746f6f6c"),
    "ur": ("88a6736368656d6102aa6d6f64656c5f68617368b037373766663532313935313830623136a97265665f706f735f63a4686f"
           "6d65a773706565645f6301a373657107aa636f6e74726f6c6c6572a464656373a565706f636803a474696d65cb41d954fc4010"
           "0000",
           "8ba6736368656d6102aa6d6f64656c5f68617368b037373766663532313935313830623136a5706f735f6da4686f6d65ab7072"
           "6f745f73746f705f6dc2a66c6f61645f6dfea66d6972726f7288a6736368656d6102aa6d6f64656c5f68617368b03737376666"
           "3532313935313830623136a97265665f706f735f63a4686f6d65a773706565645f6301a373657107aa636f6e74726f6c6c6572"
           "a464656373a565706f636803a474696d65cb41d954fc40100000a6737461747573aa736166655f7374617465a664657461696c"
           "b76e6f20636f6d6d616e642077697468696e20312e302073a373657129a474696d65cb41d954fc40600000a3687562a770692d"
           "746f6f6c"),
}


def recorded_pair(codec: Codec) -> tuple[CommandMessage, StateMessage]:
    command = codec.command({v.name: v.initial for v in codec.commands}, seq=7, controller="decs", epoch=3,
                            time=1700000000.25)
    state = codec.state({v.name: v.initial for v in codec.measured}, status=HubStatus.SAFE_STATE, seq=41,
                        hub="pi-tool", mirror=command, detail="no command within 1.0 s", time=1700000001.5)
    return command, state


@pytest.mark.parametrize("name", list(RECORDED_WIRE))
def test_messages_recorded_before_the_typed_header_encode_and_decode_the_same(name: str) -> None:
    codec = CODECS[name]
    command_hex, state_hex = RECORDED_WIRE[name]
    command, state = recorded_pair(codec)
    assert codec.encode_command(command).hex() == command_hex
    assert codec.encode_state(state).hex() == state_hex
    assert codec.decode_command(bytes.fromhex(command_hex)) == command
    decoded = codec.decode_state(bytes.fromhex(state_hex))
    assert decoded == state
    assert decoded.status is HubStatus.SAFE_STATE and decoded.mirror is not None
    assert (decoded.mirror.seq, decoded.mirror.controller, decoded.mirror.epoch) == (7, "decs", 3)


def header_of(protocol: type) -> set[str]:
    return {name for name, member in vars(protocol).items() if isinstance(member, property)}


@pytest.mark.parametrize("codec", CODECS.values(), ids=list(CODECS))
def test_every_generated_struct_has_the_typed_header(codec: Codec) -> None:
    command, state = recorded_pair(codec)
    assert isinstance(command, CommandMessage) and isinstance(state, StateMessage)
    # The protocols name exactly the envelope fields the codec adds around the variables.
    assert header_of(CommandMessage) == set(COMMAND_ENVELOPE) <= set(codec.Command.__struct_fields__)
    assert header_of(StateMessage) == set(STATE_ENVELOPE) <= set(codec.State.__struct_fields__)


# --- building checks -----------------------------------------------------------------------

def test_builders_check_domains_and_names() -> None:
    codec = CODECS["ur"]
    with pytest.raises(DomainError, match=r"ur\.ref_pos_c = 'nowhere' is outside its domain \{home, bolt1, bolt2\}"):
        a_command(codec, ref_pos_c="nowhere")
    with pytest.raises(MessageError, match=r"lacks ur\.speed_c"):
        codec.command({"ref_pos_c": "home"}, seq=1, controller="decs")
    with pytest.raises(MessageError, match="no command variable 'tool_e'"):
        a_command(codec, tool_e="none")
    with pytest.raises(DomainError, match=r"ur\.load_m = 7"):
        codec.state({"load_m": 7}, status=HubStatus.OK, seq=1, hub="h")
    with pytest.raises(MessageError, match="mirror must be a UrCommand"):
        codec.state({}, status=HubStatus.OK, seq=1, hub="h", mirror=a_command(CODECS["nr"]))


def test_reserved_field_names_are_refused() -> None:
    with pytest.raises(ValueError, match=r"x\.seq uses the reserved message field name 'seq'"):
        Codec(Resource("x", (command("x.seq"),)))


# --- domain errors on decode (hubs reject such commands) ----------------------------------------

@pytest.mark.parametrize(("resource", "field", "value", "domain"), [
    ("nr", "run_c", 1, "bool"),  # an int is not a bool
    ("nr", "run_c", "true", "bool"),
    ("nr", "run_c", None, "bool"),
    ("ur", "ref_pos_c", "unknown", "{home, bolt1, bolt2}"),  # a measured-only name
    ("ur", "speed_c", 0, "1..5"),
    ("ur", "speed_c", 6, "1..5"),
    ("ur", "speed_c", True, "1..5"),  # a bool is not an int
    ("ur", "speed_c", 2.0, "1..5"),
    ("odd", "level_c", 2, "1..5"),
    ("odd", "mix_c", "manual", "{0, auto}"),
    ("odd", "mix_c", False, "{0, auto}"),
])
def test_out_of_domain_command_is_detected(resource: str, field: str, value: object, domain: str) -> None:
    codec = CODECS[resource]
    command = a_command(codec, seq=42)
    assert isinstance(command, msgspec.Struct)  # a resource's generated struct: structs.replace takes it
    cmd = msgspec.structs.replace(command, **{field: value})
    with pytest.raises(DomainError) as caught:
        codec.decode_command(codec.encode_command(cmd))
    error = caught.value
    assert (error.resource, error.variable, error.value, error.seq, error.controller) == \
        (resource, f"{resource}.{field}", value, 42, "decs")
    assert f"{resource}.{field} = {value!r} is outside its domain" in str(error)
    if resource != "odd":
        assert error.domain == domain


def test_out_of_domain_state_and_mirror_are_detected() -> None:
    codec = CODECS["ur"]
    good = codec.state({"pos_m": "home"}, status=HubStatus.OK, seq=1, hub="ur10", mirror=a_command(codec))
    # The resource's generated structs: structs.replace takes them, and skips the domain checks of codec.state.
    # (`is not None` first: mypy 2.4 takes isinstance of an optional protocol for unreachable.)
    assert isinstance(good, msgspec.Struct) and good.mirror is not None and isinstance(good.mirror, msgspec.Struct)
    bad = msgspec.structs.replace(good, pos_m="bolt9")
    with pytest.raises(DomainError, match=r"ur\.pos_m = 'bolt9'"):
        codec.decode_state(codec.encode_state(bad))
    bad_mirror = msgspec.structs.replace(good, mirror=msgspec.structs.replace(good.mirror, speed_c=9))
    with pytest.raises(DomainError, match=r"ur\.speed_c \(mirror\) = 9"):
        codec.decode_state(codec.encode_state(bad_mirror))
    bad_odd = CODECS["odd"].State(schema=SCHEMA, model_hash=CODECS["odd"].model_hash, mix_m="x", mirror=None,
                                  status=HubStatus.OK, seq=1, time=0.0, hub="h")
    assert isinstance(bad_odd, StateMessage)  # built from the struct itself: codec.state would refuse its mix_m
    with pytest.raises(DomainError, match=r"odd\.mix_m = 'x'"):
        CODECS["odd"].decode_state(CODECS["odd"].encode_state(bad_odd))


# --- schema and model mismatches ------------------------------------------------------------------

def test_hub_and_controller_from_different_models_refuse_each_other() -> None:
    controller = Codec(robot())
    hub = Codec(robot(poses=("home", "bolt1", "bolt2", "bolt3")))
    assert controller.model_hash != hub.model_hash
    payload = controller.encode_command(a_command(controller))
    with pytest.raises(ModelMismatch) as caught:
        hub.decode_command(payload)
    message = str(caught.value)
    assert "resource ur" in message and controller.model_hash in message and hub.model_hash in message
    assert (caught.value.local, caught.value.remote) == (hub.model_hash, controller.model_hash)
    state = hub.state({}, status=HubStatus.OK, seq=1, hub="ur10")
    with pytest.raises(ModelMismatch, match=f"model hash {hub.model_hash}, ours {controller.model_hash}"):
        controller.decode_state(hub.encode_state(state))


def test_model_mismatch_even_when_the_shapes_agree() -> None:
    # Same fields, one more enum value in a domain: the typed decode would succeed.
    a = Codec(Resource("m", (command("m.x_c", Domain.enum("a", "b"), "a"),)))
    b = Codec(Resource("m", (command("m.x_c", Domain.enum("a", "b", "c"), "a"),)))
    with pytest.raises(ModelMismatch):
        b.decode_command(a.encode_command(a.command({"x_c": "a"}, seq=1, controller="c")))


def test_schema_mismatch_names_both_versions() -> None:
    codec = CODECS["nr"]
    for schema in (SCHEMA + 1, 0, "1", True):
        raw = msgspec.to_builtins(a_command(codec)) | {"schema": schema}
        with pytest.raises(SchemaMismatch, match=f"resource nr: command has message schema {schema!r}"):
            codec.decode_command(msgspec.msgpack.encode(raw))
    state = msgspec.to_builtins(codec.state({}, status=HubStatus.OK, seq=1, hub="h", mirror=a_command(codec)))
    state["mirror"]["schema"] = SCHEMA + 1
    with pytest.raises(SchemaMismatch, match="state \\(mirror\\)"):
        codec.decode_state(msgspec.msgpack.encode(state))


def test_model_hash_is_stable() -> None:
    assert model_hash(nutrunner()) == model_hash(nutrunner())
    reordered = Resource("nr", tuple(reversed(nutrunner().variables)))
    assert model_hash(reordered) == model_hash(nutrunner())
    assert model_hash(nutrunner("nr2")) != model_hash(nutrunner())
    # A golden value: the hash must not depend on the Python process (no hash(), no dict order).
    assert model_hash(nutrunner()) == "2213ce085a973cb4"
    # Estimated variables and initial values do not travel: they do not change the hash.
    plain = robot()
    assert model_hash(Resource("ur", tuple(v for v in plain.variables if v.path != "ur.tool_e"))) == \
        model_hash(plain)


def test_a_state_is_not_a_command() -> None:
    codec = CODECS["nr"]
    state = codec.encode_state(codec.state({}, status=HubStatus.OK, seq=1, hub="h"))
    with pytest.raises(MessageError, match="this is a state message"):
        codec.decode_command(state)
    with pytest.raises(MessageError, match="this is a command message"):
        codec.decode_state(codec.encode_command(a_command(codec)))


def test_mistyped_envelope_field_is_named() -> None:
    codec = CODECS["nr"]
    raw = msgspec.to_builtins(a_command(codec)) | {"seq": "7"}
    with pytest.raises(MessageError, match=r"Expected `int`, got `str` - at `\$.seq`"):
        codec.decode_command(msgspec.msgpack.encode(raw))
    raw = msgspec.to_builtins(codec.state({}, status=HubStatus.OK, seq=1, hub="h")) | {"status": "sleepy"}
    with pytest.raises(MessageError, match=r"\$.status"):
        codec.decode_state(msgspec.msgpack.encode(raw))


# --- garbage never escapes as anything but MessageError ------------------------------------------

def decode_any(codec: Codec, data: bytes) -> None:
    """Decode as command and as state: a result or MessageError, nothing else."""
    for decoder in (codec.decode_command, codec.decode_state):
        with contextlib.suppress(MessageError):
            decoder(data)


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=300), name=st.sampled_from(list(CODECS)))
def test_random_bytes_give_message_error(data: bytes, name: str) -> None:
    decode_any(CODECS[name], data)


msgpack_ints = st.integers(min_value=-(2**63), max_value=2**64 - 1)
msgpack_values = st.recursive(
    st.none() | st.booleans() | msgpack_ints | st.floats() | st.text(max_size=10) | st.binary(max_size=10),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8) | msgpack_ints, children,
                                                                      max_size=4),
    max_leaves=10,
)


@settings(max_examples=300, deadline=None)
@given(data=st.data(), name=st.sampled_from(list(CODECS)))
def test_valid_messages_with_a_field_replaced_or_removed(data: st.DataObject, name: str) -> None:
    codec = CODECS[name]
    cmd = a_command(codec)
    raw = msgspec.to_builtins(codec.state({}, status=HubStatus.OK, seq=1, hub="h", mirror=cmd))
    raw_cmd = msgspec.to_builtins(cmd)
    for message in (raw, raw_cmd, raw["mirror"]):
        key = data.draw(st.sampled_from(sorted(message)))
        if data.draw(st.booleans()):
            del message[key]
        else:
            message[key] = data.draw(msgpack_values)
    decode_any(codec, msgspec.msgpack.encode(raw))
    decode_any(codec, msgspec.msgpack.encode(raw_cmd))


@settings(max_examples=200, deadline=None)
@given(value=msgpack_values, name=st.sampled_from(list(CODECS)))
def test_random_msgpack_gives_message_error(value: object, name: str) -> None:
    decode_any(CODECS[name], msgspec.msgpack.encode(value))


@settings(max_examples=100, deadline=None)
@given(data=st.data(), name=st.sampled_from(list(CODECS)))
def test_truncated_payloads_give_message_error(data: st.DataObject, name: str) -> None:
    codec = CODECS[name]
    payload = codec.encode_state(codec.state({}, status=HubStatus.OK, seq=1, hub="h", mirror=a_command(codec)))
    cut = data.draw(st.integers(min_value=0, max_value=len(payload) - 1))
    with pytest.raises(MessageError):
        codec.decode_state(payload[:cut])
    with pytest.raises(MessageError):
        codec.decode_command(payload[:cut])


# --- plain messages --------------------------------------------------------------------------

class Health(Message):
    resource: str
    healthy: bool
    reasons: list[str] = []


def test_plain_messages_round_trip_and_refuse_other_schemas() -> None:
    health = Health(resource="nr", healthy=False, reasons=["stale state"])
    assert decode(encode(health), Health) == health
    assert health.schema == SCHEMA
    with pytest.raises(SchemaMismatch, match="Health has message schema 99"):
        decode(encode(msgspec.structs.replace(health, schema=99)), Health)
    with pytest.raises(MessageError, match="no readable schema version"):
        decode(msgspec.msgpack.encode({"resource": "nr", "healthy": True}), Health)
    with pytest.raises(MessageError, match=r"Health: Expected `bool`"):
        decode(msgspec.msgpack.encode({"schema": SCHEMA, "resource": "nr", "healthy": 3}), Health)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=100))
def test_plain_garbage_gives_message_error(data: bytes) -> None:
    with contextlib.suppress(MessageError):
        decode(data, Health)
