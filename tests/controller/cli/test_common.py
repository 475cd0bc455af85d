"""The command-line machinery both console scripts share: the registry, the exit codes of
:mod:`controller.errors` as :func:`controller.cli.common.main` maps them, the message for a missing
extra, the argparse types and the checks of output paths."""

from __future__ import annotations

import argparse
import os
import sys
import types

import pytest

import controller.cli.common as common
from controller.cli import VERBS as LEG_VERBS
from controller.cli import main as leg_main
from controller.errors import (BusError, InputError, MissingDependency, SafetyStop, UsageError)
from hil.cli import VERBS as HARNESS_VERBS


def test_every_verb_module_has_add_arguments_and_run_and_imports_nothing_heavy_at_its_top():
    """At its top a verb module imports the standard library and ``controller`` only (what it needs
    beyond is imported inside ``run``), so building the parser imports no simulation."""
    import ast
    import importlib

    allowed = set(sys.stdlib_module_names) | {"__future__", "controller"}
    for verb in LEG_VERBS + HARNESS_VERBS:
        module = importlib.import_module(verb.module)
        assert callable(module.add_arguments) and callable(module.run), verb.name
        tree = ast.parse(open(module.__file__).read())
        top = {a.name.split(".")[0] for n in tree.body if isinstance(n, ast.Import) for a in n.names}
        top |= {n.module.split(".")[0] for n in tree.body if isinstance(n, ast.ImportFrom) and n.module}
        assert top <= allowed, (verb.name, top - allowed)
    assert "numpy" not in allowed and "hil" not in allowed and "pybullet" not in allowed  # the rule can fail


def test_the_leg_offers_its_verbs_and_the_harness_reuses_the_same_modules():
    assert [v.name for v in LEG_VERBS] == ["run", "bringup", "config", "status", "arm", "disarm", "clear-faults",
                                           "estop"]
    harness = {v.name: v.module for v in HARNESS_VERBS}
    # the harness's controller, config and bringup are the leg's own modules, not copies
    assert (harness["controller"], harness["config"], harness["bringup"]) == \
        ("controller.cli.run", "controller.cli.config", "controller.cli.bringup")
    assert all(not v.needs for v in LEG_VERBS)  # the leg runs on the core install


def test_a_missing_extra_is_one_line_naming_what_to_install_exit_6(monkeypatch, capsys):
    real = common.importlib.util.find_spec
    monkeypatch.setattr(common.importlib.util, "find_spec", lambda name: None if name == "pybullet" else real(name))
    from hil.cli import main

    assert main(["walk", "--seconds", "1"]) == 6
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["elegant-stepping walk: needs pybullet, not installed here: pip install "
                   "'elegant-stepping[sim]' (or '.[sim]' in a clone)"]  # research is installed: not asked for


def test_an_invalid_configuration_is_exit_3_and_a_malformed_command_exit_2(tmp_path, capsys):
    bad = tmp_path / "leg.toml"
    bad.write_text("[axes.knee]\ngear_ratio = -6\n")
    assert leg_main(["config", "check", str(bad)]) == 3
    err = capsys.readouterr().err
    assert "axes.knee.gear_ratio = -6" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as exc:
        leg_main(["nosuchverb"])
    assert exc.value.code == 2


def test_positive_rejects_zero_negative_nan_and_words():
    parse = common.positive(float)
    assert parse("0.5") == 0.5
    for text in ("0", "-1", "nan", "inf", "soon"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)


def test_non_negative_and_bounded_take_their_edges_and_refuse_beyond():
    seed = common.non_negative(int)
    assert seed("0") == 0 and seed("7") == 7
    for text in ("-5", "1.5", "x"):
        with pytest.raises(argparse.ArgumentTypeError, match="non-negative"):
            seed(text)
    prob = common.bounded(float, 0.0, 1.0)
    assert prob("0") == 0.0 and prob("1") == 1.0
    for text in ("-0.01", "1.01", "nan", "p"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"\[0, 1\]"):
            prob(text)


def test_argparse_names_the_option_of_a_bad_seed(capsys):
    from hil.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["walk", "--seed", "-5"])
    assert exc.value.code == 2
    assert "argument --seed: must be a non-negative number, got '-5'" in capsys.readouterr().err


# -- main's mapping of exceptions to exit codes -------------------------------------------------------
def _fake_verb(monkeypatch, raised: BaseException | None, at: str = "run"):
    """A verb module ``fake`` whose ``run`` (or its import, ``at="import"``) raises ``raised``."""
    module = types.ModuleType("es_fake_verb")

    def run(args):
        raise raised

    module.add_arguments = lambda p: None
    module.run = run
    monkeypatch.setitem(sys.modules, "es_fake_verb", module)
    if at == "import":
        real = common.importlib.import_module

        def import_module(name, *a):
            if name == "es_fake_verb":
                raise raised
            return real(name, *a)

        monkeypatch.setattr(common.importlib, "import_module", import_module)
    return (common.Verb("fake", "es_fake_verb", "a verb for the test"),)


CASES = [
    (UsageError("--x: must be two"), 2, "prog fake: error: --x: must be two"),
    (InputError("f.json: not a learn run"), 3, "prog fake: error: f.json: not a learn run"),
    (BusError("cannot open the CAN bus (interface socketcan, channel can9): no such device"), 4,
     "prog fake: error: cannot open the CAN bus (interface socketcan, channel can9): no such device"),
    (SafetyStop("axis knee left closed loop"), 5, "prog fake: error: axis knee left closed loop"),
    (MissingDependency("no User-Mode Linux"), 6, "prog fake: error: no User-Mode Linux"),
    (ValueError("burst_s must be in [0.05, 5]\n  (twice)"), 3, "prog fake: error: burst_s must be in [0.05, 5] (twice)"),
    (FileNotFoundError(2, "No such file or directory", "runs/x"), 3, "prog fake: error: runs/x: No such file or directory"),
    (NotADirectoryError(20, "Not a directory", "a_file/x"), 3, "prog fake: error: a_file/x: Not a directory"),
    (OSError(28, "No space left on device", "out/m.json"), 3, "prog fake: error: out/m.json: No space left on device"),
    (KeyboardInterrupt(), 130, "prog fake: interrupted; what was finished is kept"),
]


@pytest.mark.parametrize("raised, code, line", CASES, ids=[type(c[0]).__name__ for c in CASES])
def test_main_maps_each_expected_failure_to_its_code_and_one_line(raised, code, line, monkeypatch, capsys):
    verbs = _fake_verb(monkeypatch, raised)
    assert common.main("prog", "a test", verbs, ["fake"]) == code
    out, err = capsys.readouterr()
    assert err.splitlines() == [line] and not out


@pytest.mark.parametrize("raised", [RuntimeError("oops"), KeyError("trials"), OSError(22, "Invalid argument")],
                         ids=["RuntimeError", "KeyError", "OSError-without-a-path"])
def test_a_bug_is_a_traceback_then_a_line_saying_so_exit_70(raised, monkeypatch, capsys):
    verbs = _fake_verb(monkeypatch, raised)
    assert common.main("prog", "a test", verbs, ["fake"]) == 70
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "Traceback (most recent call last):"
    assert err[-1] == "prog fake: this is a bug in elegant-stepping (the traceback above); please report it"
    assert type(raised).__name__ in err[-2]


def test_sigint_while_the_verb_module_is_imported_is_130_and_one_line(monkeypatch, capsys):
    """Start-up: the verb's heavy imports happen in run(); an interrupt there, or while the parser is
    built, is the same one line."""
    verbs = _fake_verb(monkeypatch, KeyboardInterrupt(), at="import")
    assert common.main("prog", "a test", verbs, ["fake"]) == 130
    assert capsys.readouterr().err.splitlines() == ["prog: interrupted; what was finished is kept"]


def test_a_closed_pipe_on_stdout_is_not_an_error(monkeypatch, capsys):
    verbs = _fake_verb(monkeypatch, BrokenPipeError(32, "Broken pipe"))
    monkeypatch.setattr(common.os, "dup2", lambda *a: None)  # keep this process's stdout
    assert common.main("prog", "a test", verbs, ["fake"]) == 0
    assert capsys.readouterr().err == ""


# -- output paths ------------------------------------------------------------------------------------
def test_output_paths_are_refused_before_any_work_naming_the_option(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    (tmp_path / "a_dir").mkdir()
    refused = [
        (common.check_output_file, "", "--json: an empty path"),
        (common.check_output_file, str(a_file / "m.json"), f"--json {a_file}/m.json: {a_file} is a file, not a folder"),
        (common.check_output_file, str(a_file / "deeper" / "m.json"), f"{a_file} is a file, not a folder"),
        (common.check_output_file, str(tmp_path / "a_dir"), "a folder, not a file"),
        (common.check_output_folder, "", "--json: an empty path"),
        (common.check_output_folder, str(a_file), "a file, not a folder"),
        (common.check_output_folder, str(a_file / "x"), f"{a_file} is a file, not a folder"),
    ]
    for check, path, words in refused:
        with pytest.raises(InputError, match=None) as exc:
            check(path, "--json")
        assert words in str(exc.value), (path, str(exc.value))
    for check, path in [(common.check_output_file, None), (common.check_output_file, "-"),
                        (common.check_output_file, str(tmp_path / "new" / "m.json")),
                        (common.check_output_file, str(a_file)),  # an existing file is replaced
                        (common.check_output_folder, None), (common.check_output_folder, str(tmp_path / "a_dir")),
                        (common.check_output_folder, str(tmp_path / "new" / "deeper"))]:
        check(path, "--json")
    assert not (tmp_path / "new").exists()  # checking makes nothing


def test_a_folder_that_cannot_be_written_is_refused(tmp_path, monkeypatch):
    """(Observed through ``os.access``: a test run as root could write anywhere.)"""
    asked = []
    monkeypatch.setattr(common.os, "access", lambda path, mode: asked.append((str(path), mode)) or False)
    with pytest.raises(InputError, match=r"--json .*: the folder .* is not writable"):
        common.check_output_file(str(tmp_path / "new" / "m.json"), "--json")
    assert asked == [(str(tmp_path), os.W_OK | os.X_OK)]
    with pytest.raises(InputError, match="not writable"):
        common.check_output_folder(str(tmp_path), "--out")


def test_write_json_under_a_file_is_an_input_error_naming_the_option(tmp_path):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(InputError, match=r"^--out .*a_file is a file, not a folder"):
        common.write_json(str(tmp_path / "a_file" / "x.json"), {"a": 1}, option="--out")
    common.write_json(str(tmp_path / "ok" / "x.json"), {"a": 1})
    assert (tmp_path / "ok" / "x.json").read_text() == '{\n  "a": 1\n}\n'


def test_a_warning_is_one_line_naming_the_program_and_verb(capsys):
    args = argparse.Namespace(_prog="elegant-stepping", _verb=common.Verb("decode", "m", "h"))
    common.warn(args, "bus.blf: read 7 frames,\n stopped at frame 8")
    assert capsys.readouterr().err == "elegant-stepping decode: warning: bus.blf: read 7 frames, stopped at frame 8\n"


def test_a_command_sets_one_blas_thread_unless_the_environment_chose(monkeypatch):
    """Before any verb imports numpy (OpenBLAS reads the variable when it loads); an explicit
    setting is the user's and stays."""
    monkeypatch.delenv(common.BLAS_THREADS_ENV, raising=False)
    with pytest.raises(SystemExit):
        leg_main(["--help"])
    assert os.environ[common.BLAS_THREADS_ENV] == "1"
    monkeypatch.setenv(common.BLAS_THREADS_ENV, "4")
    common.single_threaded_blas()
    assert os.environ[common.BLAS_THREADS_ENV] == "4"


def test_an_interrupt_handled_inside_string_code_still_exits_130_not_by_sigint(tmp_path):
    """CPython 3.11 flags a KeyboardInterrupt that ends any code run from a string (``exec`` of a
    string, as ``dataclasses`` does for every frozen class) as unhandled, even when a ``try``
    handles it, and then dies of SIGINT at exit (-2) instead of returning its code: a SIGTERM
    during a lazy import in ``learn`` did so about one stop in twenty. ``main`` clears the flag."""
    import subprocess
    from pathlib import Path

    script = tmp_path / "stop_at_once.py"  # run with -m, as the console script and ``python -m hil.cli`` run
    script.write_text(
        "import sys, types\n"
        "verb = types.ModuleType('stopverb')\n"
        "verb.add_arguments = lambda p: None\n"
        "def run(args):\n"
        "    try:\n"
        "        exec('raise KeyboardInterrupt')  # what a signal inside a dataclass's exec does\n"
        "    except KeyboardInterrupt:\n"
        "        print('prog stop: stopped; run it again to resume', file=sys.stderr)\n"
        "        return 130\n"
        "verb.run = run\n"
        "sys.modules['stopverb'] = verb\n"
        "from controller.cli.common import Verb, main\n"
        "sys.exit(main('prog', 'a test', [Verb('stop', 'stopverb', 'stop at once')], ['stop']))\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(common.__file__).parents[2]), str(tmp_path)])}
    done = subprocess.run([sys.executable, "-m", "stop_at_once"], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip().splitlines()[-1] == "prog stop: stopped; run it again to resume"
