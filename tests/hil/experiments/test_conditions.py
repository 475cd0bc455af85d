"""The experimental conditions: one declaration read by the command line, the experiment TOML and the learn configuration."""

from __future__ import annotations

import argparse
import dataclasses
import json

import pytest

from controller.config import ControllerConfig
from controller.errors import InputError
from hil.cli import main
from hil.experiments.conditions import SETTINGS, Conditions, add_arguments, conditions_from, read_experiment
from hil.experiments.journal import JournalWriter
from hil.experiments.learn import LearnConfig, LearningRun, config_difference, folder_state
from hil.experiments.sweep import SweepConfig, cell_config, check_folder, conditions_json


def _args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(argv)


def test_the_default_conditions_are_the_default_learn_configuration():
    assert LearnConfig(**Conditions().learn_fields()) == LearnConfig()
    assert Conditions.of_learn(LearnConfig()) == Conditions()


def test_every_condition_is_an_option_and_a_key_with_unit_range_and_default():
    p = argparse.ArgumentParser()
    add_arguments(p)
    text = p.format_help()
    for key, s in SETTINGS.items():
        assert "--" + key.replace("_", "-") in text and s.unit and s.doc
    assert set(SETTINGS) == {"rail_speed_m_s", "believed_rail_speed_m_s", "start_m", "range_noise_m", "range_dropout",
                             "obstacle_depth_m", "obstacle_heights_m"}


def test_the_command_line_wins_over_the_file_which_wins_over_the_defaults(tmp_path):
    path = tmp_path / "e.toml"
    path.write_text("rail_speed_m_s = 0.6\nstart_m = [1.5, 3.0]\nrange_dropout = 0.2\n")
    c = conditions_from(_args(["--experiment", str(path), "--rail-speed-m-s", "0.4"]))
    assert (c.rail_speed_m_s, c.start_m, c.range_dropout, c.range_noise_m) == (0.4, (1.5, 3.0), 0.2, 0.02)
    config = LearnConfig(**c.learn_fields())
    assert (config.start_min_m, config.start_max_m, config.range_dropout_prob) == (1.5, 3.0, 0.2)
    assert config.believed_rail_speed_m_s == 0.4  # told the truth unless said otherwise


@pytest.mark.parametrize("text,words", [
    ("rail_speed_m_s = 0.6\nspeed = 1\n", ("unknown key 'speed'",)),
    ('rail_speed_m_s = "fast"\n', ("rail_speed_m_s", "a number", "not a string")),
    ("start_m = [3.0, 2.0]\n", ("start_m", "MIN must not exceed MAX")),
    ("start_m = [2.0]\n", ("start_m", "2 to 2 numbers")),
    ("obstacle_heights_m = [0.06, 0.03]\n", ("obstacle_heights_m", "item 1", "taller than 3 cm")),
    ("range_dropout = 1.0\n", ("range_dropout", "[0, 0.95]")),
    ("rail_speed_m_s = \n", ("not TOML",)),
])
def test_a_bad_experiment_file_is_one_line_naming_the_file_and_the_key(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        read_experiment(path)
    message = str(exc.value)
    assert str(path) in message and "\n" not in message
    for w in words:
        assert w in message


def test_the_plant_runs_the_rail_speed_and_the_controller_is_told_its_belief():
    config = LearnConfig(**Conditions(rail_speed_m_s=0.55, believed_rail_speed_m_s=0.5, range_noise_m=0.04).learn_fields())
    ls = config.lockstep()
    assert ls.rig.rail_speed_m_s == 0.55 and ls.controller.gait.ground_speed_m_s == 0.5
    assert ls.hardware.sensor.range_noise_m == 0.04
    # the filter keeps the controller's own assumed noise: a sensor noisier than it assumes
    assert ls.controller.range_filter.noise_m == ControllerConfig().range_filter.noise_m == 0.02
    assert config.controller.gait.ground_speed_m_s == 0.5  # the header names what the controller was told
    told = LearnConfig(rail_speed_m_s=0.45)
    assert told.believed_rail_speed_m_s == 0.45 and told.controller.gait.ground_speed_m_s == 0.45
    assert told.lockstep().rig.rail_speed_m_s == 0.45


def test_mixed_heights_are_drawn_per_trial_from_the_seed():
    config = LearnConfig(trials=1, seed=5, **Conditions(obstacle_heights_m=(0.05, 0.09, 0.12)).learn_fields())
    assert config.obstacle_heights_m == (0.05, 0.09, 0.12)
    draws = []
    for _ in range(2):
        run = LearningRun(config)
        try:
            heights = []
            for _ in range(8):  # the draw alone (the trial's walk is not needed to see it)
                run.rng.uniform(config.start_min_m, config.start_max_m)
                heights.append(config.obstacle_heights_m[int(run.rng.integers(3))])
            draws.append(heights)
        finally:
            run.close()
    assert draws[0] == draws[1] and len(set(draws[0])) > 1


def _journal(out, config: LearnConfig, drop: tuple[str, ...] = ()) -> None:
    header = json.loads(json.dumps(dataclasses.asdict(config)))
    for key in drop:
        header.pop(key)
    JournalWriter.create(out / "trials.jsonl", header).close()


def test_a_folder_of_another_experiment_is_refused_naming_the_option(tmp_path):
    _journal(tmp_path, LearnConfig(trials=3))
    with pytest.raises(InputError) as exc:
        folder_state(tmp_path, LearnConfig(trials=3, rail_speed_m_s=0.6))
    assert "another experiment" in str(exc.value) and "--rail-speed-m-s" in str(exc.value)
    with pytest.raises(InputError, match="--start-m"):
        folder_state(tmp_path, LearnConfig(trials=3, start_min_m=1.5, start_max_m=3.0))
    assert folder_state(tmp_path, LearnConfig(trials=3)).kind == "resume"


def test_a_folder_written_before_the_rail_speeds_resumes_at_the_speed_it_ran():
    old = json.loads(json.dumps(dataclasses.asdict(LearnConfig())))
    for key in ("rail_speed_m_s", "believed_rail_speed_m_s"):
        old.pop(key)
    assert config_difference(old, json.loads(json.dumps(dataclasses.asdict(LearnConfig())))) is None
    faster = json.loads(json.dumps(dataclasses.asdict(LearnConfig(rail_speed_m_s=0.6))))
    assert "rail_speed_m_s" in config_difference(old, faster)


def test_a_sweep_carries_its_conditions_to_every_cell_and_refuses_other_ones(tmp_path):
    conditions = Conditions(rail_speed_m_s=0.6, range_dropout=0.2)
    config = SweepConfig(out_dir=tmp_path, seeds=(0,), obstacle_heights_m=(0.06, 0.1), methods=("none",), trials=2,
                         conditions=conditions)
    for cell in config.cells():
        learn = cell_config(cell)
        assert (learn.rail_speed_m_s, learn.range_dropout_prob) == (0.6, 0.2)
        assert learn.obstacle_height_m == cell.obstacle_height_m and learn.obstacle_heights_m == ()
    assert config.to_json()["conditions"] == conditions_json(conditions)
    (tmp_path / "config.json").write_text(json.dumps(config.to_json()))
    check_folder(tmp_path, config)
    with pytest.raises(InputError, match="rail_speed_m_s"):
        check_folder(tmp_path, dataclasses.replace(config, conditions=Conditions()))


def test_learn_runs_the_conditions_given_and_records_them_in_its_header(tmp_path, capsys):
    path = tmp_path / "e.toml"
    path.write_text("rail_speed_m_s = 0.55\nbelieved_rail_speed_m_s = 0.5\nobstacle_heights_m = [0.06, 0.1]\n")
    out = tmp_path / "run"
    argv = ["learn", "--trials", "2", "--seed", "4", "--out", str(out), "--quiet", "--no-figures", "--experiment",
            str(path), "--start-m", "2.0,2.2", "--range-dropout", "0.1"]
    assert main(argv) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    c = metrics["config"]
    assert (c["rail_speed_m_s"], c["believed_rail_speed_m_s"], c["controller"]["gait"]["ground_speed_m_s"]) == \
        (0.55, 0.5, 0.5)
    assert (c["start_min_m"], c["start_max_m"], c["range_dropout_prob"], c["obstacle_heights_m"]) == \
        (2.0, 2.2, 0.1, [0.06, 0.1])
    assert all(t["obstacle_height_m"] in (0.06, 0.1) and 2.0 <= t["start_distance_m"] <= 2.2 for t in metrics["trials"])
    capsys.readouterr()
    # the same folder with another experiment: one line naming the condition, nothing run
    assert main([*argv[:-2], "--range-dropout", "0.2"]) == 3
    err = capsys.readouterr().err
    assert "another experiment" in err and "--range-dropout" in err and "Traceback" not in err


def test_the_documented_example_experiment_reads():
    from pathlib import Path

    example = Path(__file__).resolve().parents[3] / "docs" / "experiment.example.toml"
    values = read_experiment(example)
    assert set(values) == set(SETTINGS)  # it shows every condition
    Conditions(**values)
