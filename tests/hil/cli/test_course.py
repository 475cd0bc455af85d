"""``course`` on the command line: bad values are one line and exit 2, before any simulation; a
bad folder exit 3; a short course end to end, and again (nothing to run)."""

from __future__ import annotations

import json

import pytest

from hil.cli import main
from hil.experiments import course


@pytest.fixture
def no_run(monkeypatch):
    """Fail the test if a course run is built (the refusal must come first)."""

    def built(*args, **kwargs):
        raise AssertionError("a course run was started")

    monkeypatch.setattr(course, "CourseRun", built)


@pytest.mark.parametrize("argv,words", [
    (["--gap-m", "0.3,2"], "--gap-m: MIN 0.3 m is below 0.6 m, the closest spacing the leg recovers from"),
    (["--heights-m", "0.05,0.25"], "--heights-m: the tallest, 0.25 m, for the deepest block, 0.15 m: 0.250 m is "
                                   "above the leg's"),
    (["--heights-m", "0.02,0.1"], "--heights-m: 0.02,0.1 m is outside (0.03, 0.5] m"),
    (["--depths-m", "0.05,0.5"], "--depths-m: 0.05,0.5 m is outside [0.01, 0.3] m"),
])
def test_a_range_a_course_does_not_allow_is_one_line_and_exit_2(tmp_path, capsys, no_run, argv, words):
    assert main(["course", "--obstacles", "1", "--quiet", "--out", str(tmp_path / "c"), *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("argv,option", [(["--gap-m", "3,2"], "--gap-m"), (["--heights-m", "0.1"], "--heights-m"),
                                         (["--depths-m", "a,b"], "--depths-m"), (["--obstacles", "0"], "--obstacles"),
                                         (["--methods", "paper,walrus"], "--methods"),
                                         (["--methods", "none,none"], "--methods"), (["--seed", "-1"], "--seed"),
                                         (["--window", "0"], "--window")])
def test_malformed_options_are_usage_errors_naming_the_option(tmp_path, capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        main(["course", "--out", str(tmp_path / "c"), *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"argument {option}:" in err
    assert [line for line in err.splitlines() if "error:" in line] == [err.splitlines()[-1]]
    assert not (tmp_path / "c").exists()


def test_a_bad_out_is_refused_before_any_work(tmp_path, capsys, no_run):
    (tmp_path / "a_file").write_text("mine")
    assert main(["course", "--obstacles", "1", "--quiet", "--out", str(tmp_path / "a_file")]) == 3
    err = capsys.readouterr().err
    assert "is a file, not a folder" in err and err.count("\n") == 1


def test_a_short_course_end_to_end_and_again(tmp_path, capsys):
    argv = ["course", "--obstacles", "2", "--seed", "2", "--methods", "none,oracle", "--quiet", "--window", "2",
            "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "none: " in out and "oracle: " in out and "course seed 2, 2 obstacles: success" in out
    assert (tmp_path / "figures" / "course.png").exists()
    saved = json.loads((tmp_path / "course.json").read_text())
    assert len(saved["layout"]) == 2 and saved["config"]["gap_m"] == [0.6, 3.0]
    assert main(argv) == 0
    assert "(already in the folder)" in capsys.readouterr().out
