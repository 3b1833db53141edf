"""`free_port` picks a loopback port the kernel does not hand out by itself, so that nothing on the
machine takes it between the choice and the bind of the process it is chosen for."""

from __future__ import annotations

import socket

import pytest

from common.plumbing.lifecycle import _ephemeral_ports, free_port


def test_a_free_port_is_below_the_ephemeral_range_and_can_be_bound() -> None:
    ephemeral = _ephemeral_ports()
    ports = {free_port() for _ in range(20)}
    assert all(p < ephemeral.start for p in ports), (sorted(ports), ephemeral)
    assert len(ports) > 1  # chosen at random, not one fixed port
    for port in ports:
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))


def test_a_port_in_use_is_not_chosen(monkeypatch: pytest.MonkeyPatch) -> None:
    import common.plumbing.lifecycle as process

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        monkeypatch.setattr(process, "LOWEST_CHOSEN_PORT", port)
        monkeypatch.setattr(process, "_ephemeral_ports", lambda: range(port + 2, port + 3))  # candidates: port, port+1
        chosen = {free_port() for _ in range(10)}
    assert port not in chosen
