"""Who moved a weight (hil.experiments.credit): the improved learner's lessons, watched."""

from __future__ import annotations

import numpy as np

from controller.stepping.improved import ImprovedConfig, ImprovedPremotor, Lesson
from controller.stepping.reflexes import Reflex
from hil.experiments import credit
from hil.experiments.learn import learn_config


def test_each_lesson_carries_the_weights_before_and_after_and_the_judged_gate():
    p = ImprovedPremotor(4, 28, 0.3, ImprovedConfig(tucked_contexts=0, commit_earlier_s=0.0, context_share=0.0))
    lessons: list[Lesson] = []
    p.on_lesson = lessons.append
    p.on_step_onset(0.0, 10, context=1)
    p.on_contact_reflex(Reflex("extension", 0.5, "shin", True, 0.3))
    assert len(lessons) == 1
    lesson = lessons[0]
    assert (lesson.kind, lesson.cell, lesson.row, lesson.t_s) == ("extension", 10, 1, 0.5)
    assert not lesson.before_s.any() and np.array_equal(lesson.after_s, p.weights)
    assert lesson.after_s[1, 10] > lesson.after_s[1, 11] > 0.0  # the spread
    line = credit.lesson_line(7, lesson, 1, 11)
    assert line is not None
    assert line.startswith("trial 7 extension judged at cell 10 row 1 (tuck 0.00): w[1,11] +0.000 -> +")
    assert credit.lesson_line(7, lesson, 1, 20) is None  # not moved: no line


def test_a_lesson_is_not_made_unless_watched():
    p = ImprovedPremotor(4, 28, 0.3)
    p.on_step_onset(0.0, 10, context=1)
    p.on_reflex("extension", 0.5)  # no watcher: learns as before, nothing to call
    assert p.weights[1, 10] > 0.0 and p.on_lesson is None


def test_the_watched_run_names_the_spread_that_set_a_crossing_weight():
    """Tuning seed 63 at 0.08 m (seed 59 before rule 24 moved the paths): trial 5's too-close
    placement, judged at an empty gate, set the tucked crossing cell 6's weight (row 1) through
    the spread."""
    lines = credit.watch(learn_config("improved", seed=63, trials=6, obstacle_height_m=0.08), 1, 6)
    moved = [line for line in lines if "w[1,6]" in line]
    assert moved and moved[0].startswith("trial 5 placement judged at cell - row -"), lines
    assert any(line.startswith("trial 5 failed:") for line in lines), lines


def test_bad_input_is_one_line_and_exit_2(capsys):
    assert credit.main(["--seed", "1", "--row", "9", "--cell", "0"]) == 2
    assert credit.main(["--seed", "1", "--row", "0", "--cell", "0", "--trials", "0"]) == 2
    assert credit.main(["--seed", "1", "--row", "0", "--cell", "0", "--heights", "0.3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("credit: error: ") for line in err)
