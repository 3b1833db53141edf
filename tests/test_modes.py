"""The modes of hubs.toml as enums: the command line reads them as members and refuses others by their words."""

from __future__ import annotations

import argparse

import pytest

from common.config.modes import DeviceMode, NetworkMode, SecurityMode, argument, words
from hubs.main import add_selftest_arguments


def test_the_words_are_those_of_hubs_toml() -> None:
    assert words(DeviceMode) == ("emulate", "sim", "real")
    assert words(NetworkMode) == ("peer", "client")
    assert words(SecurityMode) == ("tls", "insecure")


def test_a_mode_option_gives_the_member() -> None:
    parser = argparse.ArgumentParser()
    add_selftest_arguments(parser)
    assert parser.parse_args(["pi-tool", "--mode", "sim"]).mode is DeviceMode.SIM
    assert parser.parse_args(["pi-tool"]).mode is None


def test_an_unknown_mode_is_refused_naming_the_words(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser(prog="hub")
    parser.add_argument("--mode", type=argument(DeviceMode), choices=list(DeviceMode))
    with pytest.raises(SystemExit):
        parser.parse_args(["--mode", "simulate"])
    error = capsys.readouterr().err
    assert "argument --mode: invalid choice: 'simulate' (choose from emulate, sim, real)" in error
    assert "[--mode {emulate,sim,real}]" in error
