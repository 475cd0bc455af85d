"""The learning experiment end to end, through the whole stack in lockstep."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hil.cli import main
from hil.experiments.learn import LearnConfig, run_learning

TRIAL_KEYS = {"index", "success", "reflexes", "footfalls_m", "burst_s", "gated_decisions"}


@pytest.mark.slow
def test_a_short_run_learns_and_the_frozen_baseline_does_not():
    learned = run_learning(LearnConfig(trials=40, seed=3))
    frozen = run_learning(LearnConfig(trials=40, seed=3, learning=False))
    s_learned = learned["summary"]["success_21_40"]
    s_frozen = frozen["summary"]["success_21_40"]
    assert s_learned >= 0.8, learned["summary"]
    assert s_frozen <= 0.6, frozen["summary"]
    # the learner changed its strides because of reflexes, the baseline never did
    assert sum(t["gated_decisions"] for t in learned["trials"][20:]) > 20
    assert all(t["gated_decisions"] == 0 for t in frozen["trials"])
    kinds = {r["kind"] for t in learned["trials"] for r in t["reflexes"]}
    assert kinds == {"extension", "placement"}


def _without_wall_clock(metrics: dict) -> str:
    m = json.loads(json.dumps(metrics))
    for key in ("wall_s", "trials_per_minute"):
        m["summary"].pop(key)
    return json.dumps(m, sort_keys=True)


def test_same_seed_same_metrics_and_another_seed_differs():
    a = run_learning(LearnConfig(trials=3, seed=11))
    b = run_learning(LearnConfig(trials=3, seed=11))
    c = run_learning(LearnConfig(trials=3, seed=12))
    assert _without_wall_clock(a) == _without_wall_clock(b)
    assert _without_wall_clock(a) != _without_wall_clock(c)


def test_learn_command_writes_metrics_and_weights(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["learn", "--trials", "2", "--seed", "1", "--out", str(out), "--quiet",
                 "--obstacle-height-m", "0.07", "--range-noise-m", "0.01"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["config"]["obstacle_height_m"] == 0.07 and metrics["config"]["range_noise_m"] == 0.01
    assert [t["index"] for t in metrics["trials"]] == [0, 1]
    for trial in metrics["trials"]:
        assert TRIAL_KEYS <= trial.keys()
        assert all(r["kind"] in ("extension", "placement") for r in trial["reflexes"])
        assert all(x < 0 for x in trial["footfalls_m"]) and len(trial["footfalls_m"]) >= 4
    assert {"wall_s", "sim_s"} <= metrics["summary"].keys()
    assert metrics["config"]["method"] == "improved"  # learn's default: a row of weights per height context
    with np.load(out / "weights.npz", allow_pickle=False) as data:
        assert data["weights"].shape == (4, 28) and float(data["cell_width_m"]) == 0.04
    assert {p.name for p in (out / "figures").iterdir()} >= {f"{name}.{ext}" for ext in ("png", "svg") for name in
                                                             ("learning_curve", "footfall_spread", "weights")}
    assert "wrote" in capsys.readouterr().out
    assert main(["learn", "--trials", "2", "--seed", "1", "--out", str(out), "--quiet", "--obstacle-height-m", "0.07",
                 "--range-noise-m", "0.01"]) == 0  # the same command again: finished, nothing runs
    assert "already holds this finished run" in capsys.readouterr().out


@pytest.mark.parametrize("argv,code,match", [
    (["--obstacle-height-m", "0.02"], 2, "obstacle_height_m"),  # a condition out of its range: argparse's
    (["--trials", "0"], 2, "argument --trials"),  # a malformed option: usage, argparse names it
    (["--seed", "-5"], 2, "argument --seed"),
])
def test_bad_learn_arguments_get_a_clear_error(tmp_path, capsys, argv, code, match):
    try:
        got = main(["learn", "--out", str(tmp_path / "x"), "--quiet", *argv])
    except SystemExit as exc:  # argparse's usage error
        got = exc.code
    assert got == code
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()  # refused before anything was written


def test_analyze_reads_learn_folders_and_refuses_others(tmp_path, capsys):
    out = tmp_path / "run"
    run_learning(LearnConfig(trials=2, seed=2), out_dir=out)
    assert main(["analyze", str(out), "--json", str(tmp_path / "a.json")]) == 0
    figures = json.loads((tmp_path / "a.json").read_text())
    assert figures["runs"][0]["trials"] == 2 and len(figures["footfall_std_m_by_steps_before"]) == 4
    assert main(["analyze", str(tmp_path / "nothing")]) == 3
    assert "no metrics.json" in capsys.readouterr().err


# -- issue 18: contacts in every record, stalls, the leg's limit, a premotor's lift ----------------

def test_contact_misses_count_the_contacts_no_reflex_heard():
    from hil.experiments.learn import MISS_SLACK_S, contact_misses

    contacts = [[1.0, 1.1], [1.5, 1.6], [3.0, 3.0]]
    assert contact_misses(contacts, [], 1.0) == 3
    assert contact_misses(contacts, [1.001], 1.0) == 1  # the second is the same collision, still refractory
    assert contact_misses(contacts, [1.1 + MISS_SLACK_S], 0.0) == 2  # heard just after it ended
    assert contact_misses(contacts, [1.1 + 2 * MISS_SLACK_S], 0.0) == 3  # too late: another event
    assert contact_misses(contacts, [0.5, 2.5], 0.2) == 3


def test_every_record_carries_its_contacts_and_the_misses_are_counted():
    m = run_learning(LearnConfig(trials=4, seed=3))
    for t in m["trials"]:
        assert t["success"] == (not t["contacts"] and not t["stalled"])
        assert 0 <= t["contact_misses"] <= len(t["contacts"])
        assert all(0.0 < a <= b < t["sim_s"] for a, b in t["contacts"])
    assert m["summary"]["contact_misses"] == sum(t["contact_misses"] for t in m["trials"])
    assert any(t["contacts"] for t in m["trials"])  # seed 3 fails at first: something was counted


def test_a_carriage_caught_on_the_block_ends_the_trial_as_a_stalled_mistake():
    # 0.21 m: within the leg's limit, beyond what the hardwired lift clears; seed 0 wedges the foot
    # on the block in its second trial (the carriage stopped: without the deadline it never ended)
    m = run_learning(LearnConfig(trials=2, seed=0, obstacle_height_m=0.21))
    stalled = [t for t in m["trials"] if t["stalled"]]
    assert stalled and not any(t["success"] for t in stalled)
    from hil.experiments.learn import STALL_S

    for t in stalled:
        assert t["sim_s"] > STALL_S


def test_heights_beyond_the_legs_limit_are_refused_with_the_reason():
    with pytest.raises(ValueError, match=r"obstacle height: 0\.240 m is above the leg's 0\.223 m limit .*knee"):
        LearnConfig(obstacle_heights_m=(0.08, 0.24))
    with pytest.raises(ValueError, match="0.216 m limit"):  # a deeper block: a lower limit
        LearnConfig(obstacle_height_m=0.22, obstacle_depth_m=0.20)
    assert LearnConfig(obstacle_height_m=0.22).obstacle_height_m == 0.22


def test_the_loop_takes_a_premotors_lift_within_its_bounds_and_gives_it_each_reflex_in_full():
    from controller.loop import MAX_LIFT_AMPLITUDE, MIN_LIFT_AMPLITUDE
    from controller.stepping.learner import AdaptivePremotor
    from hil.experiments.learn import LearningRun

    class Lifting:  # the controller's premotor, by composition (a compiled class takes no Python subclass)
        def __init__(self, asked: float) -> None:
            self.inner = AdaptivePremotor(28, 0.3)
            self.weights = self.inner.weights
            self.on_step_onset, self.burst_s, self.gated_weight = (
                self.inner.on_step_onset, self.inner.burst_s, self.inner.gated_weight)
            self.asked, self.heard = asked, []

        def on_reflex(self, kind, now_s):
            self.inner.on_reflex(kind, now_s)

        def lift_amplitude(self, gated_range_m, context):
            return self.asked

        def on_contact_reflex(self, reflex):
            self.heard.append(reflex)

    heard = 0
    for asked, expected in ((2.5, 2.5), (9.0, MAX_LIFT_AMPLITUDE), (0.2, MIN_LIFT_AMPLITUDE), (math.nan, None)):
        p = Lifting(asked)
        run = LearningRun(LearnConfig(trials=2, seed=3), premotor=p)
        try:
            run.run()
            amplitudes = {s.amplitude for s in run.ls.loop.stats.steps}
            if expected is None:  # a NaN: the hardwired reflex's
                assert amplitudes == {1.0, run.config.controller.reflexes.lift_amplitude}
            else:
                assert amplitudes == {expected}, asked
            assert p.heard == run.ls.loop.stats.reflexes  # every reflex, in full
            assert not p.weights.any()  # on_reflex was not called as well
            heard += len(p.heard)
        finally:
            run.close()
    assert heard  # (some run had a reflex to hear)


class _ControllersPremotor:
    """The controller's own premotor by composition (a compiled class takes no subclass), for a
    test to add one of the hooks the loop asks a premotor for."""

    def __init__(self) -> None:
        from controller.stepping.learner import AdaptivePremotor

        self.inner = AdaptivePremotor(28, 0.3)
        self.on_step_onset, self.burst_s, self.gated_weight, self.on_reflex = (
            self.inner.on_step_onset, self.inner.burst_s, self.inner.gated_weight, self.inner.on_reflex)


def test_the_loop_gives_a_tucked_swing_the_descent_its_premotor_asks_for():
    """Rule 18 of controller.stepping.improved: a premotor's ``tucked_descend_phase``, asked at
    each gate, shapes that cycle's tucked swing; NaN keeps the gait's. A fully tucked lift with a
    late descent walks differently from the same lift with the gait's descent."""
    from hil.experiments.learn import LearningRun

    class Descending(_ControllersPremotor):
        def __init__(self, descend: float) -> None:
            super().__init__()
            self.descend, self.asked = descend, 0

        def lift_amplitude(self, gated_range_m, context):
            return 3.44 if gated_range_m is not None and gated_range_m < 0.4 else 1.0

        def tucked_descend_phase(self):
            self.asked += 1
            return self.descend

    records = {}  # the whole trial's record, by whether a descent was asked for
    for descend in (math.nan, 0.9):
        p = Descending(descend)
        run = LearningRun(LearnConfig(trials=1, seed=3, obstacle_height_m=0.16), premotor=p)
        try:
            records[descend == descend] = run.run()[0]
            assert p.asked == len(run.ls.loop.stats.steps)  # once per gate
        finally:
            run.close()
    assert records[True] != records[False]


def test_the_loop_tells_the_stance_the_speed_its_premotor_asks_for_at_each_touchdown():
    """Rule 19 of controller.stepping.improved: a premotor's ``stance_speed_m_s``, asked at each
    touchdown, sets how fast the stance sweeps back; NaN keeps the gait's. A stance told 0.45 m/s
    walks differently from the gait's own 0.5 m/s, and the trajectory holds the speed told."""
    from hil.experiments.learn import LearningRun

    class Sweeping(_ControllersPremotor):
        def __init__(self, speed: float) -> None:
            super().__init__()
            self.speed, self.asked = speed, 0

        def stance_speed_m_s(self):
            self.asked += 1
            return self.speed

    records, backs = {}, {}
    for speed in (math.nan, 0.45):
        p = Sweeping(speed)
        run = LearningRun(LearnConfig(trials=1, seed=3), premotor=p)
        try:
            records[speed == speed] = run.run()[0]
            loop = run.ls.loop
            swings = sum(1 for s in loop.stats.steps if s.swing_s == s.swing_s)  # each ended swing
            assert swings - 1 <= p.asked <= swings + 1  # once per touchdown
            backs[speed == speed] = loop.trajectory.x_back_m
        finally:
            run.close()
    gait, cpg = LearnConfig().controller.gait, LearnConfig().controller.cpg
    assert backs[False] == gait.foot_ahead_m - gait.ground_speed_m_s * cpg.stance_s
    assert math.isclose(backs[True], gait.foot_ahead_m - 0.45 * cpg.stance_s, abs_tol=1e-12)
    assert records[True] != records[False]


def test_the_oracle_lifts_for_the_true_height_and_as_before_at_low_ones():
    from hil.experiments.oracle import OraclePremotor

    ctl = LearnConfig().controller
    height = [0.16]
    o = OraclePremotor(ctl, lambda: 1.0, height=lambda: height[0])
    assert o.lift_amplitude(0.3, 0) == pytest.approx((0.16 + 0.07) / 0.08)
    assert o.lift_amplitude(0.5, 0) == 1.0  # beyond the lift range: no lift, as the reflex
    height[0] = 0.08
    assert o.lift_amplitude(0.3, 0) == ctl.reflexes.lift_amplitude  # the hardwired lift
    height[0] = 0.22
    assert o.lift_amplitude(0.3, 0) < (0.22 + 0.07) / 0.08  # within the leg's limit (3.44)


def test_a_kept_trial_of_before_the_contact_fields_is_checked_on_the_fields_it_has(tmp_path):
    from hil.experiments.learn import NotReproduced, _check_rerun

    rerun = {"index": 0, "success": True, "contacts": [], "stalled": False, "contact_misses": 0, "sim_s": 5.0}
    _check_rerun(rerun, {"index": 0, "success": True, "sim_s": 5.0}, 0, tmp_path / "trials.jsonl")
    with pytest.raises(NotReproduced, match="sim_s"):
        _check_rerun(rerun, {"index": 0, "success": True, "sim_s": 5.5}, 0, tmp_path / "trials.jsonl")
    with pytest.raises(NotReproduced):  # a kept record with the fields: checked on them too
        _check_rerun(rerun, {**rerun, "contact_misses": 1}, 0, tmp_path / "trials.jsonl")


def test_run_calls_the_trial_hooks_around_each_trial_in_order():
    from hil.experiments.learn import LearningRun

    run = LearningRun(LearnConfig(trials=3, seed=3))
    calls: list[tuple] = []
    try:
        records = run.run(before_trial=lambda i: calls.append(("before", i, len(run.trials))),
                          after_trial=lambda i, t: calls.append(("after", i, t["index"], t is run.trials[-1])))
    finally:
        run.close()
    assert len(records) == 3
    assert calls == [("before", 0, 0), ("after", 0, 0, True), ("before", 1, 1), ("after", 1, 1, True),
                     ("before", 2, 2), ("after", 2, 2, True)]


def test_a_tools_list_of_one_height_is_one_height_not_a_mix_of_one():
    from hil.experiments.learn import learn_config, one_or_mixed

    assert one_or_mixed((0.08,)) == 0.08
    assert one_or_mixed((0.04, 0.08)) == (0.04, 0.08)
    assert learn_config("improved", seed=1, trials=2, obstacle_height_m=one_or_mixed((0.08,))).obstacle_heights_m == ()
    assert learn_config("improved", seed=1, trials=2, obstacle_height_m=(0.08,)).obstacle_heights_m == (0.08,)
