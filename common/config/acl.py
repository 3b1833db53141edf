"""The Zenoh `access_control` section of a station in `tls` mode, derived from hubs.toml and the model.

Every process enforces the same policy on each of its links; a link's subject is the
common name of the certificate its peer presented (mutual TLS, common/config/security.py), so
a peer cannot claim a name its certificate does not carry. Default: deny.

What each holder may SEND (checked on ingress, where it matters: a peer's own process
is not trusted to check itself):

* a hub: `put` only its own resources' `state` and its `selftest`; its `alive`
  liveliness token; the `selftest` queryable and its replies; subscribe to its own
  resources' `cmd` (and the `cmd` of the resources the model's effects on its devices
  read, for emulated devices), to any `state` and to `ctl/**`.
* the controller: `put` `cmd` and `ctl/**`, answer `ctl/**` queries, hold `ctl/**`
  liveliness tokens, subscribe to and query anything of the station.
* an operator ([security] operators: consoles, hubctl, an MES): query `ctl/request`, `ctl/orders`
  (add, list and cancel orders) and the hubs' `selftest`, subscribe to `ctl/**`, `state` and `selftest`, watch `alive`.
* the viewer ([overview] name: the supervisors' overview page) only reads: subscribe to `ctl/**` and `state`,
  query `ctl/status` and `ctl/plan/*` (the controller's picture and plans), watch `alive`.
  It may put nothing and query neither `ctl/request` nor `ctl/orders`.

What a process sends TO an authenticated station member is not restricted beyond the
station's keys: data only flows to a peer whose subscriptions and queryables passed
the checks above, so a hub certificate that may not subscribe to another hub's `cmd`
receives none.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from common.config.hubs_toml import StationConfig
from common.config.security import roles_of
from common.model import Model, TransitionKind
from common.wire.keys import Keys
from common.wire.orders import ORDERS_KEY

ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


@dataclass(frozen=True)
class Grant:
    """Messages of these kinds on these key expressions are allowed."""

    messages: tuple[str, ...]
    keys: tuple[str, ...]


def hub_grants(keys: Keys, hub: str, resources: Iterable[str], followed: Iterable[str]) -> list[Grant]:
    own = sorted(resources)
    ctl = keys.ctl("**")
    return [
        Grant(("put",), (*(keys.state(r) for r in own), keys.selftest(hub))),
        Grant(("liveliness_token",), (keys.alive(hub), *(keys.call(hub, r) for r in own))),
        Grant(("declare_queryable", "reply"), (keys.selftest(hub),)),
        Grant(("declare_subscriber",), (*(keys.cmd(r) for r in sorted({*own, *followed})), keys.all_state, ctl)),
        Grant(("declare_liveliness_subscriber", "liveliness_query"), (ctl,)),
    ]


def controller_grants(keys: Keys) -> list[Grant]:
    ctl, everything = keys.ctl("**"), f"{keys.station}/**"
    return [
        Grant(("put",), (keys.all_cmd, ctl)),
        Grant(("declare_queryable", "reply", "liveliness_token"), (ctl,)),
        Grant(("declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"), (everything,)),
    ]


def operator_grants(keys: Keys) -> list[Grant]:
    ctl = keys.ctl("**")
    return [
        # The console asks for the full status on connect and for the plans it shows, as the viewer does.
        Grant(("query",), (keys.ctl("request"), keys.ctl(ORDERS_KEY), keys.all_selftest, keys.ctl("status"),
                           keys.all_plans)),
        Grant(("declare_subscriber",), (ctl, keys.all_state, keys.all_selftest)),
        Grant(("declare_liveliness_subscriber", "liveliness_query"), (keys.all_alive, ctl)),
    ]


def viewer_grants(keys: Keys) -> list[Grant]:
    return [
        Grant(("query",), (keys.ctl("status"), keys.all_plans)),
        Grant(("declare_subscriber",), (keys.ctl("**"), keys.all_state)),
        Grant(("declare_liveliness_subscriber", "liveliness_query"), (keys.all_alive, keys.ctl("**"))),
    ]


def followed_resources(model: Model, resources: Iterable[str]) -> set[str]:
    """The other resources whose variables the model's effects on `resources` read or write:
    what an emulated device of these resources follows (hubs/runtime.py `_external_inputs`)."""
    own = set(resources)
    followed: set[str] = set()
    for transition in model.ability_transitions:
        if transition.kind is not TransitionKind.EFFECT:
            continue
        paths = transition.guard.paths() | transition.written()
        if {p.split(".", 1)[0] for p in transition.written()} & own:
            followed |= {p.split(".", 1)[0] for p in paths}
    return followed - own


def _rules(prefix: str, grants: Sequence[Grant], flow: str) -> list[dict[str, Any]]:
    return [{"id": f"{prefix}-{i}", "messages": list(g.messages), "flows": [flow], "permission": "allow",
             "key_exprs": list(g.keys)} for i, g in enumerate(grants)]


def access_control(config: StationConfig, model: Model) -> dict[str, Any]:
    """The `access_control` section every process of the station runs with (zenoh 1.x schema)."""
    keys = config.keys
    rules = _rules("to-station", [Grant(ALL_MESSAGES, (f"{keys.station}/**",))], "egress")
    subjects, policies = [], []
    for name, role in roles_of(config).items():
        subject = f"{role}-{name}"
        if role == "hub":
            devices = config.hubs[name].devices
            grants = hub_grants(keys, name, devices, followed_resources(model, devices))
        else:
            grants = {"controller": controller_grants, "operator": operator_grants,
                      "viewer": viewer_grants}[role](keys)
        own_rules = _rules(f"from-{subject}", grants, "ingress")
        rules += own_rules
        subjects.append({"id": subject, "cert_common_names": [name]})
        policies.append({"id": f"{subject}-sends", "rules": [r["id"] for r in own_rules], "subjects": [subject]})
    policies.append({"id": "station-receives", "rules": ["to-station-0"], "subjects": [s["id"] for s in subjects]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
