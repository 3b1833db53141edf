"""The modes of hubs.toml, as the code compares them: how a device runs, how a process joins the
network, how the station's links are protected, how the controller's plans are executed.

StrEnums: msgspec reads and writes each as its string, so hubs.toml, the command line and every
file that holds one keep the words they had; code compares the members, never the words.
"""

from __future__ import annotations

import argparse
import enum
from collections.abc import Callable
from typing import TypeVar


class DeviceMode(enum.StrEnum):
    """How a hub runs one device (DESIGN §6): the controller cannot tell the three apart."""

    EMULATE = "emulate"  # the model's effects, no hardware
    SIM = "sim"  # the real driver against a simulator speaking the device's protocol
    REAL = "real"  # the real driver against the device


class NetworkMode(enum.StrEnum):
    """How a process joins zenoh (`[network] mode`)."""

    PEER = "peer"  # direct links: the controller listens, hubs connect to it
    CLIENT = "client"  # every process connects to zenoh routers (a client cannot listen)


class SecurityMode(enum.StrEnum):
    """How the station's links are protected (`[security] mode`, common/config/security.py)."""

    TLS = "tls"  # mutual TLS on every link, access control by certificate
    INSECURE = "insecure"  # plain TCP: a single-machine `hubctl up` only


class Execution(enum.StrEnum):
    """How a plan's steps wait for each other (`[controller] execution`, `hubctl up --execution`;
    controller/deorder.py)."""

    # Causal links and threats: the operator works while the robot does. A plan that counts on an enabled effect
    # waiting for it (the nutrunner's reset while a slow operator confirms pipe 1: the shortest plan records
    # pipe 2 on pipe 1's torque) is left at the same place again and again when dispatched this early: plans are
    # checked in time before use (controller/timed_check.py), and one this order breaks runs in a stricter one.
    PARTIAL_ORDER = "partial_order"
    TRACE = "trace"  # every earlier step sharing a variable, a command every earlier reader of its device
    SEQUENCE = "sequence"  # every earlier step: the plan as the planner wrote it, one step after another

    @classmethod
    def _missing_(cls, value: object) -> Execution | None:
        # Recordings made before hubs.toml could choose the order spelt it "partial-order".
        return cls.PARTIAL_ORDER if value == "partial-order" else None


# hubs.toml's, and every engine's without one. Not the partial order yet: in fresh-clone suites its five-order run
# over processes at speed 4 did physical work twice, plans relying on one effect beating another by less than the
# processes' latency under load (see README, Execution).
DEFAULT_EXECUTION = Execution.TRACE


def words(mode: type[enum.StrEnum]) -> tuple[str, ...]:
    """A mode's words in declared order: the list an error shows."""
    return tuple(member.value for member in mode)


Mode = TypeVar("Mode", bound=enum.StrEnum)


def argument(mode: type[Mode]) -> Callable[[str], Mode]:
    """argparse's `type` for an option taking a mode (`--mode sim`): the member, or argparse's own
    "invalid choice" error listing the words (its default would name the enum class instead)."""

    def parse(text: str) -> Mode:
        try:
            return mode(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"invalid choice: {text!r} (choose from {', '.join(words(mode))})") from None

    parse.__name__ = mode.__name__
    return parse
