"""The one bus-precedence rule: command line over the configuration file over python-can's own."""

from __future__ import annotations

import pytest

from controller.settings.daemon import bus_kwargs, daemon_settings
from controller.settings.file import BusSettings, ConfigError


def test_without_a_file_only_what_was_given_is_passed():
    assert bus_kwargs("virtual", "x", None) == {"interface": "virtual", "channel": "x"}
    assert bus_kwargs(None, None, None) == {}  # python-can's config file / environment decide


def test_the_command_line_overrides_the_file_key_by_key():
    file = BusSettings(interface="socketcan", channel="can0", bitrate=500_000)
    assert bus_kwargs(None, None, None, file=file) == {"interface": "socketcan", "channel": "can0", "bitrate": 500_000}
    assert bus_kwargs(None, "can1", None, file=file) == {"interface": "socketcan", "channel": "can1", "bitrate": 500_000}
    assert bus_kwargs("virtual", "x", 125_000, file=file) == {"interface": "virtual", "channel": "x", "bitrate": 125_000}


def test_a_file_without_a_bus_section_is_refused_not_run_on_can0(tmp_path, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    path = tmp_path / "leg.toml"
    path.write_text("[controller]\nrate_hz = 250.0\n")
    with pytest.raises(ConfigError, match=r"\[bus\]: missing; .* a real CAN bus"):
        daemon_settings(path, bitrate=250_000)


def test_a_file_with_part_of_a_bus_section_takes_its_defaults_not_python_cans(tmp_path, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    path = tmp_path / "leg.toml"
    path.write_text("[bus]\nchannel = \"vcan0\"\n[controller]\nrate_hz = 250.0\n")
    d = daemon_settings(path, bitrate=250_000)
    assert d.bus_kw == {"interface": "socketcan", "channel": "vcan0", "bitrate": 250_000}
    assert d.controller.rate_hz == 250.0
