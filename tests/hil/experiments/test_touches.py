"""A trial's contacts step by step (hil.experiments.touches): the replay is the learning run's
own trial, and its rows say what the switches, the ground truth and PyBullet saw."""

from __future__ import annotations

from hil.experiments import touches
from hil.experiments.learn import run_learning, learn_config
from hil.experiments.touches import Step


def step(t_s: float, touching: bool = False, points=()) -> Step:
    return Step(t_s, 0.12, 0.001, True, False, touching, False, 0.133, tuple(points))


def test_the_rows_around_each_contact_episode_and_what_a_row_says():
    steps = [step((t + 0.5) / 1000.0) for t in range(5000, 5600)]  # off the window's edges
    windows = touches.around_contacts(steps, [[5.2, 5.21], [5.4, 5.5]], before_s=0.01, after_s=0.005)
    assert [len(w) for w in windows] == [25, 115]
    assert windows[0][0].t_s == 5.1905 and windows[0][-1].t_s == 5.2145
    text = touches.row(step(5.523, True, [("foot", "block", -0.00022, 61.2), ("foot", "ground", 0.0, 0.0)]))
    assert text == "  5.523 +0.1200 +0.0010 F.T stance 0.133 foot>block d=-0.22mm f=61.2N foot>ground d=0.00mm f=0.0N"


def test_the_replayed_trial_is_the_learning_runs_own_and_its_touches_lie_in_its_contacts():
    """Tuning seed 46 fails its first trial at 0.08 m (improved): the replay gives that trial's
    record, field for field, and the ground truth's touching steps are its contact episodes."""
    config = learn_config("improved", seed=46, trials=1, obstacle_height_m=0.08)
    record, steps = touches.replay(config, 0)
    learnt = run_learning(config)["trials"][0]
    assert record == learnt
    assert not record["success"] and record["contacts"]
    touching = [s for s in steps if s.touching]
    assert touching, "the failed trial's replay saw no touch"
    for s in touching:
        assert any(a - 1e-9 <= s.t_s <= b + 1e-9 for a, b in record["contacts"]), s
        assert any(body == "block" for _, body, _, _ in s.points), s
    lines = touches.header(record)
    assert lines[0].startswith("trial 0: height 0.08 m, failed")


def test_bad_input_is_one_line_and_exit_2(capsys):
    assert touches.main(["--seed", "1", "--trial", "0", "--heights", "0.30"]) == 2  # above the leg's limit
    assert touches.main(["--seed", "1", "--trial", "-1"]) == 2
    assert touches.main(["--seed", "1", "--trial", "0", "--method", "nonesuch"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("touches: error: ") for line in err)


def test_heights_that_are_not_numbers_are_one_line(capsys):
    assert touches.main(["--seed", "1", "--trial", "0", "--heights", "0.08,x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "touches: error: obstacle_heights_m: '0.08,x' is not a comma list of heights in metres"
