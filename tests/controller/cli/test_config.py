"""``elegant-stepping-leg config check|confirm``: a calibration is confirmed by a person on a bring-up
that passed, never assumed; a real bus's configuration is complete or refused; auto_arm only on a
simulated bus."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import stat
import time
from pathlib import Path

import pytest

from controller.bringup.checklist import Checklist, Status
from controller.bringup.procedure import BringupReport
from controller.cli import main
from controller.settings.file import (CalibrationSettings, ConfigError, config_from_dict, load_config, tomllib,
                                      with_calibration)

REPO = Path(__file__).resolve().parents[3]
ODRIVE = REPO / "configs" / "odrive-leg.toml"
SIM = REPO / "configs" / "sim.toml"


def leg_file(tmp_path: Path) -> Path:
    """A copy of the real leg's example: can0, complete, not confirmed."""
    path = tmp_path / "leg.toml"
    shutil.copy(ODRIVE, path)
    return path


def report(tmp_path: Path, *, failed: str | None = None, nodes=(("hip", 0), ("knee", 1)), move: bool = True,
           name: str = "report.json") -> Path:
    """A bring-up report as `bringup --json` writes it (BringupReport.to_dict), written after the config."""
    checklist = Checklist()
    checklist.add("hip (node 0): heartbeat", Status.PASS, "heard")
    for axis, _ in nodes:
        checklist.add(f"{axis}: firmware", Status.PASS, "firmware 0.6.10")
        checklist.add(f"{axis}: position", Status.PASS, "inside")
        for item in ("closed loop", "move", "move back"):
            checklist.add(f"{axis}: {item}", Status.PASS if move else Status.SKIP, "ok" if move else "not moved: --no-move")
    if failed:
        checklist.add(failed, Status.FAIL, "latched: ESTOP_REQUESTED")
    checklist.add("all axes IDLE", Status.PASS, "hip IDLE, knee IDLE")
    rep = BringupReport("can0", checklist, {a: {"node_id": n} for a, n in nodes}, {"node_id": 16}, {"frames": 10}, 6.2)
    path = tmp_path / name
    path.write_text(json.dumps(rep.to_dict(), indent=2))
    future = time.time() + 5  # after the configuration's last change
    os.utime(path, (future, future))
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(["config", *map(str, argv)])
    out = capsys.readouterr()
    return rc, out.out, out.err


# --------------------------------------------------------------------------- check
def test_check_of_an_unconfirmed_leg_exits_0_with_one_warning_saying_how_to_confirm(tmp_path, capsys):
    path = leg_file(tmp_path)
    rc, out, err = run(capsys, "check", path)
    assert rc == 0 and out.startswith(f"{path}: OK: socketcan can0") and "calibration NOT confirmed" in out
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"WARNING: {path}: calibration not confirmed")
    assert "cannot arm" in lines[0] or "will not arm" in lines[0]
    assert f"elegant-stepping-leg bringup --config {path} --json report.json" in lines[0]
    assert f"elegant-stepping-leg config confirm {path} --bringup report.json" in lines[0]
    rc, _, err = run(capsys, "check", SIM)  # the simulation: confirmed, no warning
    assert rc == 0 and err == ""


def test_check_of_an_empty_file_for_can0_names_everything_missing(tmp_path, capsys):
    path = tmp_path / "empty.toml"
    path.write_text("# nothing yet\n")
    rc, out, err = run(capsys, "check", path)
    assert rc == 3 and not out
    assert f"{path}: [bus]: missing; without it the bus is bus.interface = \"socketcan\", bus.channel = \"can0\"" in err
    for axis in ("hip", "knee"):
        assert (f"{path}: [axes.{axis}] node_id, gear_ratio, direction, zero_offset_rev, min_rad, max_rad: not given; "
                f"on a real CAN bus") in err
    assert "never a real leg's calibration" in err and err.rstrip().endswith("3 problems")


def test_a_partial_file_for_a_real_bus_names_only_the_missing_keys(tmp_path, capsys):
    text = ODRIVE.read_text()
    path = tmp_path / "partial.toml"
    path.write_text(re.sub(r"(?m)^zero_offset_rev = .*\n", "", text, count=1).replace("bitrate = 1000000", ""))
    rc, _, err = run(capsys, "check", path)
    assert rc == 3
    assert f"{path}: [bus] bitrate: not given; on a real CAN bus (bus.interface = \"socketcan\", bus.channel = " \
           "\"can0\") the file must give its interface, channel, bitrate itself" in err
    assert f"{path}: [axes.hip] zero_offset_rev: not given" in err and "[axes.knee]" not in err


@pytest.mark.parametrize("bus", [{"interface": "virtual"}, {"channel": "vcan0"}, {"channel": "vcan12"},
                                 {"interface": "virtual", "channel": "can0"}])
def test_a_simulated_bus_keeps_the_defaults_and_may_auto_arm(bus):
    cfg = config_from_dict({"bus": bus, "controller": {"auto_arm": True}})
    assert cfg.controller.auto_arm is True and cfg.simulated_bus
    assert cfg.controller.axes == config_from_dict({"bus": bus}).controller.axes


@pytest.mark.parametrize("bus", [{"interface": "socketcan", "channel": "can0", "bitrate": 1000000},
                                 {"interface": "socketcan", "channel": "can1", "bitrate": 500000},
                                 {"interface": "pcan", "channel": "PCAN_USBBUS1", "bitrate": 1000000}])
def test_auto_arm_on_a_real_bus_is_refused_naming_both_bus_fields(bus):
    data = json.loads(json.dumps({"bus": bus}))
    data.update(_leg_axes())
    config_from_dict(data)  # complete: accepted without auto_arm
    data["controller"] = {"auto_arm": True}
    with pytest.raises(ConfigError) as exc:
        config_from_dict(data)
    assert len(exc.value.problems) == 1
    problem = exc.value.problems[0]
    assert problem.startswith(f"controller.auto_arm = true with bus.interface = \"{bus['interface']}\", "
                              f"bus.channel = \"{bus['channel']}\": ")
    assert "bus.interface \"virtual\"" in problem and "starting with \"vcan\"" in problem
    assert "elegant-stepping-leg arm" in problem


def test_auto_arm_with_the_default_bus_is_refused_too():
    with pytest.raises(ConfigError, match=r"controller.auto_arm = true with bus.interface = \"socketcan\", "
                                          r"bus.channel = \"can0\" \(the defaults\)"):
        config_from_dict({"controller": {"auto_arm": True}, **_leg_axes()})


def _leg_axes() -> dict:
    cfg = load_config(ODRIVE)
    return {"axes": {a.name: {k: getattr(a, k) for k in ("node_id", "gear_ratio", "direction", "zero_offset_rev",
                                                         "min_rad", "max_rad")} for a in cfg.controller.axes}}


# --------------------------------------------------------------------------- confirm
def test_confirm_writes_the_calibration_keeps_the_comments_and_a_backup(tmp_path, capsys):
    path = leg_file(tmp_path)
    os.chmod(path, 0o640)
    before = path.read_text()
    rep = report(tmp_path)
    rc, out, err = run(capsys, "confirm", path, "--bringup", rep)
    assert rc == 0, err
    assert f"{path}: calibration confirmed at " in out and f"{path}.bak" in out and "every comment kept" in out
    assert Path(f"{path}.bak").read_text() == before
    cfg = load_config(path)
    assert cfg.calibration.confirmed is True and cfg.armable_reason() is None
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", cfg.calibration.confirmed_at)
    assert cfg.calibration.bringup.startswith("12 passed, 0 failed on can0: ") and str(rep.resolve()) in \
        cfg.calibration.bringup and "\n" not in cfg.calibration.bringup
    # only the three [calibration] lines changed: every comment and every other line is the same
    old, new = before.splitlines(), path.read_text().splitlines()
    assert len(old) == len(new)
    changed = [(a, b) for a, b in zip(old, new) if a != b]
    assert [b.split(" = ")[0] for _, b in changed] == ["confirmed", "confirmed_at", "bringup"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o640  # the mode kept (the daemon's group reads it)
    assert cfg == dataclasses.replace(load_config(Path(f"{path}.bak")), calibration=cfg.calibration)
    rc, _, err = run(capsys, "check", path)
    assert rc == 0 and err == ""  # confirmed: no warning


def test_confirm_rewrites_a_file_it_cannot_edit_by_lines_and_says_the_comments_are_in_the_backup(tmp_path, capsys):
    path = leg_file(tmp_path)
    # [calibration] given as a dotted key before the first table: not edited by lines, the whole file is written
    text = path.read_text()
    text = text[:text.index("\n[calibration]\n") + 1]
    path.write_text(text.replace("# An ODrive-based leg", "calibration.confirmed = false\n# An ODrive-based leg", 1))
    assert load_config(path).calibration.confirmed is False
    rep = report(tmp_path)
    rc, out, err = run(capsys, "confirm", path, "--bringup", rep)
    assert rc == 0, err
    assert "its comments are in the copy only" in out and f"{path}.bak" in out
    assert path.read_text().startswith("# elegant-stepping configuration, rewritten by `elegant-stepping-leg config "
                                       "confirm`")
    assert load_config(path).calibration.confirmed is True
    assert "calibration.confirmed = false" in Path(f"{path}.bak").read_text()


def test_with_calibration_appends_a_table_where_there_is_none():
    cal = CalibrationSettings(True, "2025-01-31T12:00:00Z", "27 passed")
    text = "[bus]\nchannel = \"vcan0\"  # a comment\n\n"
    out = with_calibration(text, cal)
    assert out.startswith(text.rstrip("\n")) and out.endswith(
        '[calibration]\nconfirmed = true\nconfirmed_at = "2025-01-31T12:00:00Z"\nbringup = "27 passed"\n')
    assert config_from_dict(tomllib.loads(out)).calibration == cal
    partial = "[calibration]  # mine\nconfirmed = false # not yet\n[bus]\nchannel = \"vcan0\"\n"
    out = with_calibration(partial, cal)
    assert out.splitlines()[:4] == ["[calibration]  # mine", 'confirmed_at = "2025-01-31T12:00:00Z"',
                                    'bringup = "27 passed"', "confirmed = true"]


@pytest.mark.parametrize("case,words", [
    ("missing", ["cannot read the bring-up report", "No such file", "--json"]),
    ("not json", ["is not a bring-up report", "--json"]),
    ("other json", ["is not a bring-up report"]),
    ("failed", ["the bring-up did not pass (12 passed, 1 failed)", "fix what failed"]),
    ("no move", ["item 'hip: move' is SKIP, not PASS", "--no-move"]),
    ("other nodes", ["is a bring-up of hip node 0, knee node 2, this configuration has hip node 0, knee node 1"]),
    ("other axes", ["is a bring-up of hip node 0, this configuration has hip node 0, knee node 1"]),
    ("older", ["is older than", "the configuration changed after that bring-up"]),
])
def test_confirm_refuses_in_one_line_and_leaves_the_file_alone(case, words, tmp_path, capsys):
    path = leg_file(tmp_path)
    before = path.read_text()
    rep = tmp_path / "report.json"
    if case == "not json":
        rep.write_text("PASS everything\n")
    elif case == "other json":
        rep.write_text(json.dumps({"passed": True, "summary": "x"}))
    elif case == "failed":
        rep = report(tmp_path, failed="knee: errors")
    elif case == "no move":
        rep = report(tmp_path, move=False)
    elif case == "other nodes":
        rep = report(tmp_path, nodes=(("hip", 0), ("knee", 2)))
    elif case == "other axes":
        rep = report(tmp_path, nodes=(("hip", 0),))
    elif case == "older":
        rep = report(tmp_path)
        past = path.stat().st_mtime - 60
        os.utime(rep, (past, past))
    if case in ("not json", "other json"):
        future = time.time() + 5
        os.utime(rep, (future, future))
    rc, out, err = run(capsys, "confirm", path, "--bringup", rep)
    assert rc == 3 and not out
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("config confirm: refused: "), err
    for word in words:
        assert word in lines[0], lines[0]
    assert path.read_text() == before and not Path(f"{path}.bak").exists()
    assert load_config(path).armable_reason() is not None


def test_confirm_of_a_bad_configuration_names_its_problems(tmp_path, capsys):
    path = tmp_path / "empty.toml"
    path.write_text("")
    rc, out, err = run(capsys, "confirm", path, "--bringup", report(tmp_path))
    assert rc == 3 and not out and "[bus]: missing" in err and not Path(f"{path}.bak").exists()


def test_confirm_that_cannot_write_the_file_is_one_line_exit_3(tmp_path, capsys, monkeypatch):
    import controller.settings.file as settings_file

    path = leg_file(tmp_path)
    rep = report(tmp_path)

    def denied(target, text):
        raise PermissionError(13, "Permission denied", str(target))

    monkeypatch.setattr(settings_file, "write_text_atomic", denied)  # as a user who is not root
    rc, out, err = run(capsys, "confirm", path, "--bringup", rep)
    assert rc == 3 and not out
    assert err.splitlines() == [f"config confirm: {path}: cannot write it: Permission denied (as root: sudo)"]


def test_confirm_needs_the_report_option(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["config", "confirm", str(ODRIVE)])
    assert exc.value.code == 2 and "--bringup" in capsys.readouterr().err
