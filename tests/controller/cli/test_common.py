"""The command-line machinery both console scripts share: the registry, exit codes, the message
for a missing extra."""

from __future__ import annotations

import pytest

import controller.cli.common as common
from controller.cli import VERBS as LEG_VERBS
from controller.cli import main as leg_main
from hil.cli import VERBS as HARNESS_VERBS


def test_every_verb_module_has_add_arguments_and_run_and_imports_nothing_heavy_at_its_top():
    import ast
    import importlib

    for verb in LEG_VERBS + HARNESS_VERBS:
        module = importlib.import_module(verb.module)
        assert callable(module.add_arguments) and callable(module.run), verb.name
        tree = ast.parse(open(module.__file__).read())
        top = {a.name.split(".")[0] for n in tree.body if isinstance(n, ast.Import) for a in n.names}
        top |= {n.module.split(".")[0] for n in tree.body if isinstance(n, ast.ImportFrom) and n.module}
        assert top <= {"__future__", "argparse", "json", "sys", "pathlib", "math", "controller", "typing", "logging"}, \
            (verb.name, top)


def test_the_leg_offers_its_verbs_and_the_harness_reuses_the_same_modules():
    assert [v.name for v in LEG_VERBS] == ["run", "bringup", "config", "status", "arm", "disarm", "clear-faults",
                                           "estop"]
    harness = {v.name: v.module for v in HARNESS_VERBS}
    # the harness's controller, config and bringup are the leg's own modules, not copies
    assert (harness["controller"], harness["config"], harness["bringup"]) == \
        ("controller.cli.run", "controller.cli.config", "controller.cli.bringup")
    assert all(not v.needs for v in LEG_VERBS)  # the leg runs on the core install


def test_a_missing_extra_is_one_line_naming_what_to_install(monkeypatch, capsys):
    real = common.importlib.util.find_spec
    monkeypatch.setattr(common.importlib.util, "find_spec", lambda name: None if name == "pybullet" else real(name))
    from hil.cli import main

    assert main(["walk", "--seconds", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["elegant-stepping walk: needs pybullet, not installed here: pip install "
                   "'elegant-stepping[sim]' (or '.[sim]' in a clone)"]  # research is installed: not asked for


def test_bad_input_is_exit_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "leg.toml"
    bad.write_text("[axes.knee]\ngear_ratio = -6\n")
    assert leg_main(["config", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "axes.knee.gear_ratio = -6" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as exc:
        leg_main(["nosuchverb"])
    assert exc.value.code == 2


def test_positive_rejects_zero_negative_nan_and_words():
    import argparse

    parse = common.positive(float)
    assert parse("0.5") == 0.5
    for text in ("0", "-1", "nan", "inf", "soon"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)
