"""``benchtwin record`` takes where to connect from python-can's configuration when no flag says otherwise."""

from __future__ import annotations

import argparse

import pytest

from benchtwin.commands.record import python_can_defaults
from benchtwin.errors import ConfigError


@pytest.fixture
def clean_can_env(monkeypatch, tmp_path):
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/can.conf or ~/.canrc of the machine
    return tmp_path


def _args(**kw) -> argparse.Namespace:
    base = {"transport": None, "host": None, "port": None}
    base.update(kw)
    return argparse.Namespace(**base)


def test_defaults_without_configuration(clean_can_env):
    assert python_can_defaults(_args(), ["vehicle", "dyno"]) == ("socketcand", "127.0.0.1", 29536, {})


def test_environment_variables_choose_interface_endpoint_and_channel(clean_can_env, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "socketcand")
    monkeypatch.setenv("CAN_CONFIG", '{"host": "127.0.0.1", "port": 31234}')
    assert python_can_defaults(_args(), ["vehicle"]) == ("socketcand", "127.0.0.1", 31234, {})
    monkeypatch.setenv("CAN_INTERFACE", "socketcan")
    monkeypatch.setenv("CAN_CHANNEL", "vcan3")
    assert python_can_defaults(_args(), ["instrument"]) == ("socketcan", "127.0.0.1", 29536,
                                                           {"instrument": "vcan3"})
    # several buses: one configured channel cannot name them all; the bus names stay the interfaces
    assert python_can_defaults(_args(), ["instrument", "dyno"])[3] == {}


def test_can_conf_file_is_read(clean_can_env):
    (clean_can_env / "can.conf").write_text("[default]\ninterface = socketcand\nhost = 127.0.0.1\nport = 30001\n")
    assert python_can_defaults(_args(), ["vehicle"]) == ("socketcand", "127.0.0.1", 30001, {})


def test_flags_win_over_the_configuration(clean_can_env, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "socketcand")
    monkeypatch.setenv("CAN_CONFIG", '{"port": 31234}')
    assert python_can_defaults(_args(port=29999), ["vehicle"])[2] == 29999
    monkeypatch.setenv("CAN_INTERFACE", "socketcan")
    assert python_can_defaults(_args(transport="socketcand"), ["vehicle"])[:3] == ("socketcand", "127.0.0.1", 29536)


def test_an_interface_record_cannot_use_is_a_config_error(clean_can_env, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    with pytest.raises(ConfigError, match="virtual"):
        python_can_defaults(_args(), ["vehicle"])
