"""The method registry: one place that names every method, cheap to import, and what each builds."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hil.experiments import methods
from hil.experiments.learn import LearnConfig, learn_config


def test_the_registry_names_every_method_once():
    assert methods.METHODS == ("paper", "context", "none", "oracle", "rl", "improved")
    assert set(methods.DEFAULT_SWEEP_METHODS) <= set(methods.METHODS)
    assert methods.DEFAULT_SWEEP_METHODS[0] == methods.DEFAULT_METHOD  # a sweep compares the default first
    # learn's default is the learner that won on held-out seeds; a configuration that names no
    # method (sessions, benchmarks, the fault matrix) runs the controller's own, the deployed one
    assert methods.DEFAULT_METHOD == "improved"
    assert methods.CONTROLLER_METHOD == "paper" == LearnConfig().method


def test_learn_runs_the_default_method_unless_told():
    import argparse

    from hil.cli.learn import add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p)
    assert p.parse_args(["--out", "x"]).method == methods.DEFAULT_METHOD
    assert p.parse_args(["--out", "x", "--method", "paper"]).method == "paper"
    help_text = p.format_help()
    assert f"default {methods.DEFAULT_METHOD}" in " ".join(help_text.split())
    for name, m in methods.REGISTRY.items():
        assert m.name == name and m.label and m.sentence in ("criterion", "success", None)
    assert [n for n, m in methods.REGISTRY.items() if not m.learns] == ["none"]


def test_unknown_names_are_refused_and_the_old_alias_is_only_for_reading():
    with pytest.raises(ValueError, match="unknown method 'magic'; choose from paper, context"):
        methods.get("magic")
    with pytest.raises(ValueError, match="learner"):
        methods.get("learner")  # new runs take registry names only
    with pytest.raises(ValueError, match="unknown method"):
        LearnConfig(method="learner")
    assert methods.resolve("learner") is methods.REGISTRY["paper"]
    assert methods.resolve("rl") is methods.REGISTRY["rl"]


def test_learn_config_of_each_method():
    c = learn_config("none", seed=2, trials=3, obstacle_height_m=0.06)
    assert (c.method, c.learning, c.obstacle_height_m, c.obstacle_heights_m) == ("none", False, 0.06, ())
    assert LearnConfig(method="none").learning is False  # learn --method none: no adaptation
    assert LearnConfig(method="rl").learning is True and LearnConfig(method="paper", learning=False).learning is False
    c = learn_config("paper", seed=2, trials=3, obstacle_height_m=(0.06, 0.1))
    assert (c.method, c.learning, c.obstacle_height_m, c.obstacle_heights_m) == ("paper", True, 0.06, (0.06, 0.1))


def test_the_builders_give_the_premotor_of_each_method():
    from controller.motion.reach import max_lift_amplitude
    from controller.stepping.context import ContextPremotor
    from controller.stepping.improved import ImprovedPremotor
    from controller.stepping.rl import QLearningPremotor
    from hil.experiments.oracle import OraclePremotor

    ctl = LearnConfig().controller
    built = {n: methods.get(n).build(ctl, methods.get(n).learns, 0, lambda: None, lambda: None)
             for n in methods.METHODS}
    assert built["paper"] is None and built["none"] is None  # the controller's own premotor
    assert isinstance(built["oracle"], OraclePremotor)
    assert isinstance(built["rl"], QLearningPremotor)
    assert isinstance(built["context"], ContextPremotor)
    improved = built["improved"]
    assert isinstance(improved, ImprovedPremotor)
    # its lift starts at the hardwired reflex's and may rise to the leg's limit (0.275 m held / 0.08 m)
    assert improved.config.lift_amplitude == ctl.reflexes.lift_amplitude
    assert improved.config.lift_max == pytest.approx(max_lift_amplitude(geometry=ctl.geometry, axes=ctl.axes))
    assert 3.3 < improved.config.lift_max < 3.5


def test_parsing_method_names_imports_no_simulation():
    code = ("import sys; from hil.experiments.sweep import SweepConfig, parse_methods; "
            "SweepConfig(out_dir='x', methods=parse_methods('paper,none,oracle,rl,context')); "
            "heavy = [m for m in ('pybullet', 'firmware_sim', 'hil.experiments.learn') if m in sys.modules]; "
            "print(heavy); sys.exit(1 if heavy else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_improved_learner_hears_the_ground_speed_its_range_filter_measures():
    """Through the whole stack (plant, bus, loop): with the plant 10% faster than the controller
    believes, the closing speeds the loop hands the learner at its gates bring its ground speed
    to the plant's within the first trial, and the tucked contexts' range with it."""
    from hil.experiments.learn import LearningRun

    config = LearnConfig(seed=3, trials=1, method="improved", rail_speed_m_s=0.55, believed_rail_speed_m_s=0.5)
    premotor = methods.build_improved(config.controller)
    assert premotor.ground_speed_m_s == 0.5
    heard: list[float] = []
    observe = premotor.observe_closing_speed
    premotor.observe_closing_speed = lambda v, var: (heard.append(v), observe(v, var))[1]
    run = LearningRun(config, premotor=premotor)
    try:
        run.run()
    finally:
        run.close()
    assert len(heard) >= 3 and all(abs(v - 0.55) < 0.05 for v in heard)
    assert premotor.ground_speed_m_s == pytest.approx(0.55, abs=0.005)


def test_the_improved_learner_asks_for_its_own_longest_burst_and_its_tucked_burst_matches_it():
    """Rule 24's ``longest_burst_s``: 0.7 s by default, whatever the CPG's configured bound, and the
    tucked swing's extra burst follows it; 0 leaves the CPG's bound (as before round 25)."""
    from dataclasses import replace

    from controller.config import ControllerConfig

    controller = ControllerConfig()
    default = methods.build_improved(controller)
    assert default.longest_burst_s == 0.7 and controller.cpg.burst_max_s == 0.6
    assert default._tucked_extra_s == pytest.approx(0.7 - controller.cpg.burst_s)
    own = methods.build_improved(controller, longest_burst_s=0.0)
    assert own.longest_burst_s is None
    assert own._tucked_extra_s == pytest.approx(controller.cpg.burst_max_s - controller.cpg.burst_s)
    other = replace(controller, cpg=replace(controller.cpg, burst_max_s=0.8))
    assert methods.build_improved(other, longest_burst_s=0.0)._tucked_extra_s == pytest.approx(0.5)
    assert methods.build_improved(other)._tucked_extra_s == pytest.approx(0.4)
    with pytest.raises(ValueError, match="longest_burst_s must be 0"):
        methods.build_improved(controller, longest_burst_s=0.2)
