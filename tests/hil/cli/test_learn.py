"""``learn`` on the command line: a bad --out is refused before any work, in one line, exit 3."""

from __future__ import annotations

import pytest

from hil.cli import main
from hil.experiments import learn


@pytest.fixture
def no_run(monkeypatch):
    """Fail the test if a learning run is built (the refusal must come first)."""

    def built(*args, **kwargs):
        raise AssertionError("a learning run was started")

    monkeypatch.setattr(learn, "LearningRun", built)


@pytest.mark.parametrize("out,words", [
    ("", ["--out: an empty path"]),
    ("{tmp}/a_file", ["--out {tmp}/a_file: is a file, not a folder"]),
    ("{tmp}/a_file/run", ["--out {tmp}/a_file/run: {tmp}/a_file is a file, so no folder can be made under it"]),
    ("/proc/no-such-folder/run", ["--out /proc/no-such-folder/run: cannot be written here"]),
])
def test_a_bad_out_is_refused_before_any_work(tmp_path, capsys, no_run, out, words):
    (tmp_path / "a_file").write_text("mine")
    assert main(["learn", "--trials", "1", "--quiet", "--out", out.replace("{tmp}", str(tmp_path))]) == 3
    err = capsys.readouterr().err
    assert [w.replace("{tmp}", str(tmp_path)) in err for w in words] == [True] * len(words), err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert (tmp_path / "a_file").read_text() == "mine"


def test_a_folder_of_other_things_is_refused_even_with_overwrite(tmp_path, capsys, no_run):
    (tmp_path / "thesis.tex").write_text("precious")
    assert main(["learn", "--trials", "1", "--quiet", "--out", str(tmp_path), "--overwrite"]) == 3
    err = capsys.readouterr().err
    assert "holds files that are not a learn run's (thesis.tex)" in err and "--overwrite clears only" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "thesis.tex"]


@pytest.mark.parametrize("argv,option", [(["--seed", "-5"], "--seed"), (["--trials", "0"], "--trials"),
                                         (["--trials", "x"], "--trials"),
                                         (["--range-noise-m", "-1"], "--range-noise-m")])
def test_malformed_options_are_usage_errors_naming_the_option(tmp_path, capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        main(["learn", "--out", str(tmp_path / "run"), *argv])
    assert exc.value.code == 2 and f"argument {option}:" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
