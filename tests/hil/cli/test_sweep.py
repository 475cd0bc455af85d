"""``sweep`` on the command line: malformed options are usage errors naming the option; a bad --out
is refused before any cell, in one line."""

from __future__ import annotations

import pytest

from hil.cli import main


@pytest.mark.parametrize("argv,option", [
    (["--seeds", "2-1"], "--seeds"), (["--seeds", "a"], "--seeds"), (["--obstacle-heights-m", "0.06,x"],
                                                                     "--obstacle-heights-m"),
    (["--methods", "paper,magic"], "--methods"), (["--methods", ","], "--methods"), (["--trials", "0"], "--trials"),
    (["--workers", "0"], "--workers"),
])
def test_malformed_options_are_usage_errors_naming_the_option(tmp_path, capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        main(["sweep", "--out", str(tmp_path / "s"), "--quiet", *argv])
    assert exc.value.code == 2 and f"argument {option}:" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("out,words", [("", "--out: an empty path"), ("{tmp}/a_file", "is a file, not a folder"),
                                       ("{tmp}/a_file/s", "a_file is a file, so no folder can be made under it")])
def test_a_bad_out_is_refused_in_one_line(tmp_path, capsys, out, words):
    (tmp_path / "a_file").write_text("mine")
    assert main(["sweep", "--out", out.replace("{tmp}", str(tmp_path)), "--seeds", "0", "--methods", "none",
                 "--trials", "1", "--quiet"]) == 3
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert (tmp_path / "a_file").read_text() == "mine"
