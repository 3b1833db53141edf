"""The RFID reader: the operator is verified once a badge is scanned (an effect: the operator does it)."""

from __future__ import annotations

from common.model import Duration, Phase, Resource, ability, measured

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# The operator scanning a badge.
DURATION = Duration.fixed(0.4)


def rfid(name: str = "rfid") -> Resource:
    verified_m = measured(f"{name}.verified_m", description="a valid operator badge was scanned")
    verify = ability(
        f"{name}.verify",
        executing=Phase(~verified_m, effects=[f"{verified_m.path} := true"]),
        finished=verified_m,
    )
    return Resource(name, (verified_m,), (verify,), device_type="rfid")
