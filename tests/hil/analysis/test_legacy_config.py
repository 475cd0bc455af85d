"""Legacy JSON controller configurations (replay of sessions recorded before TOML)."""

from __future__ import annotations

import json

import pytest

from controller.config import ControllerConfig
from hil.analysis.legacy_config import controller_config_from_dict, controller_config_to_dict, load_controller_config


def test_a_written_config_reads_back_equal(tmp_path):
    cfg = ControllerConfig()
    path = tmp_path / "controller.json"
    path.write_text(json.dumps(controller_config_to_dict(cfg)))
    assert load_controller_config(path) == cfg


def test_a_partial_config_overrides_only_what_it_names():
    cfg = controller_config_from_dict({"rate_hz": 250, "learner": {"learning": False}})
    assert cfg.rate_hz == 250 and cfg.learner.learning is False
    assert cfg.cpg == ControllerConfig().cpg


def test_unknown_keys_and_bad_values_are_clear_errors():
    with pytest.raises(ValueError, match="no such setting"):
        controller_config_from_dict({"learner": {"learnin": False}})
    with pytest.raises(ValueError, match="rate_hz"):
        controller_config_from_dict({"rate_hz": 1.0})
