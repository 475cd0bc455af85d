"""A person watching (``walk --gui``, ``learn --gui``; :mod:`hil.experiments.gui`, docs/gui.md).

Under Xvfb (``xvfb-run``, which .ci/run installs; its absence fails these tests, it does not skip
them): the walk's screenshot shows the leg, large and in the middle, in the PNG's own pixels and
by the segmentation mask; the window changes no record (learn and walk, with and without it); the
run's configuration does not know about the window. Without a display, ``--gui`` is one line and
exit 2, before PyBullet could end the process.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hil.cli import main
from hil.experiments import gui

ROOT = Path(__file__).resolve().parents[3]
SCREEN = "-screen 0 1280x1024x24"
SHOT_LINE = re.compile(r"the leg is ([0-9.]+)% of the pixels, ([0-9]+)% wide and ([0-9]+)% high; "
                       r"the rig ([0-9.]+)%, an obstacle ([0-9.]+)%")
THIGH_RGB, SHANK_RGB = (0.2, 0.4, 0.8), (0.9, 0.5, 0.1)  # urdf/gait_rig.urdf's blue and orange


def xvfb_run() -> str:
    found = shutil.which("xvfb-run")
    if found is None:
        pytest.fail("xvfb-run is not installed: apt-get install -y xvfb libgl1-mesa-dri xauth "
                    "(.ci/run installs it; these tests need it and do not skip)")
    return found


def under_xvfb(args: list[str], cwd: Path, timeout: float = 300.0) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "XAUTHORITY")}
    return subprocess.run([xvfb_run(), "-a", "-s", SCREEN, sys.executable, "-m", "hil.cli", *args],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def shot_numbers(stderr: str) -> dict[str, float]:
    found = SHOT_LINE.search(stderr)
    assert found, f"no screenshot line in:\n{stderr[-3000:]}"
    leg, wide, high, rig, obstacle = (float(v) / 100.0 for v in found.groups())
    return {"leg": leg, "wide": wide, "high": high, "rig": rig, "obstacle": obstacle}


def leg_pixels(path: Path) -> np.ndarray:
    """Where the PNG's pixels have the thigh's or the shank's colour (any shade of it: lit faces
    are brighter, shaded ones darker), as a boolean mask."""
    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=float)
    found = np.zeros(rgb.shape[:2], dtype=bool)
    brightness = rgb.sum(axis=2, keepdims=True) + 1e-9
    for colour in (THIGH_RGB, SHANK_RGB):
        want = np.array(colour) / sum(colour)
        found |= (np.abs(rgb / brightness - want).max(axis=2) < 0.06) & (rgb.sum(axis=2) > 60)
    return found


@pytest.mark.slow
def test_walk_gui_screenshot_shows_the_leg_large_and_central(tmp_path):
    shot = tmp_path / "walk.png"
    done = under_xvfb(["walk", "--gui", "--seconds", "2", "--quiet", "--seed", "1", "--json", "gui.json",
                       "--screenshot", str(shot)], tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout == ""  # PyBullet's window thread printed on stderr, not into the JSON's stream
    metrics = json.loads((tmp_path / "gui.json").read_text())
    assert metrics["phase"] == "walk" and metrics["sim_s"] == pytest.approx(2.0)
    assert metrics["wall_s"] >= 2.0  # real time: simulated time never ran ahead of the wall clock

    with Image.open(shot) as img:
        assert img.format == "PNG" and img.size == (1024, 768)  # the window's own size
    numbers = shot_numbers(done.stderr)
    # the leg (thigh, shank, foot) by the segmentation mask: a 3 cm wide leg 0.5 m long, close up
    assert 0.005 <= numbers["leg"] <= 0.05, numbers
    assert 0.30 <= numbers["high"] <= 0.80, numbers  # about half the frame's height
    assert numbers["rig"] > numbers["leg"] and numbers["obstacle"] == 0.0
    # and in the PNG's own pixels: the thigh's blue and the shank's orange, in the middle of the frame
    mask = leg_pixels(shot)
    fraction = mask.mean()
    assert 0.004 <= fraction <= 0.05, fraction
    assert fraction == pytest.approx(numbers["leg"], rel=0.5)  # the foot is black: not counted here
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    assert 0.15 * w < xs.mean() < 0.85 * w and 0.15 * h < ys.mean() < 0.85 * h
    assert (ys.max() - ys.min()) / h >= 0.25

    # the same walk without a window: the same records
    assert main(["walk", "--seconds", "2", "--quiet", "--seed", "1", "--json", str(tmp_path / "direct.json")]) == 0
    assert main(["compare", str(tmp_path / "direct.json"), str(tmp_path / "gui.json")]) == 0


@pytest.mark.slow
def test_learn_gui_changes_no_record_and_is_not_part_of_the_run(tmp_path, capsys):
    shot = tmp_path / "learn.png"
    # short approaches (the obstacle 1.2-1.5 m ahead) and no pacing: PyBullet's GUI mode is slow on a
    # loaded host with a software renderer (docs/gui.md, Speed)
    run = ["learn", "--trials", "2", "--seed", "3", "--start-m", "1.2,1.5", "--no-figures", "--quiet"]
    done = under_xvfb([*run, "--out", "with_gui", "--gui", "--gui-speed", "inf", "--screenshot", str(shot)], tmp_path,
                      timeout=600.0)
    assert done.returncode == 0, done.stderr[-3000:]
    numbers = shot_numbers(done.stderr)
    assert numbers["obstacle"] > 0.005 and 0.005 <= numbers["leg"] <= 0.05, numbers  # the leg at the obstacle
    assert shot.stat().st_size > 0

    direct = tmp_path / "direct"
    assert main([*run, "--out", str(direct)]) == 0
    capsys.readouterr()
    assert main(["compare", str(direct), str(tmp_path / "with_gui")]) == 0
    assert "per-trial records identical: True; summary identical: True" in capsys.readouterr().err
    # the run's identity (trials.jsonl's header, metrics.json's config) knows nothing of the window
    header = [json.loads((d / "trials.jsonl").read_text().splitlines()[0]) for d in (direct, tmp_path / "with_gui")]
    assert header[0] == header[1] and "gui" not in json.dumps(header[0]).lower()
    # so the same command without --gui finds this run finished: nothing to run again
    assert main([*run, "--out", str(tmp_path / "with_gui")]) == 0
    assert "already holds this finished run" in capsys.readouterr().out


def one_line_refusal(capsys, argv: list[str], code: int, words: list[str], usage: bool = False) -> None:
    """``argv`` exits ``code`` with one line naming ``words`` (argparse's own refusals print the
    usage above it and exit themselves: ``usage``)."""
    if usage:
        with pytest.raises(SystemExit) as exited:
            main(argv)
        assert exited.value.code == code
    else:
        assert main(argv) == code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1 and all(w in lines[0] for w in words), err
    if not usage:
        assert err.count("\n") == 1, err


def test_gui_without_a_display_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    one_line_refusal(capsys, ["walk", "--gui", "--seconds", "1", "--quiet"], 2,
                     ["--gui needs a display: DISPLAY is not set", "xvfb-run"])
    one_line_refusal(capsys, ["learn", "--gui", "--trials", "1", "--quiet", "--out", str(tmp_path / "run")], 2,
                     ["--gui needs a display: DISPLAY is not set"])
    assert not (tmp_path / "run").exists()  # refused before the run folder was made
    # a display that no X server answers on
    free = next(n for n in range(4321, 4400) if not Path(f"/tmp/.X11-unix/X{n}").exists())
    monkeypatch.setenv("DISPLAY", f":{free}")
    one_line_refusal(capsys, ["walk", "--gui", "--seconds", "1", "--quiet"], 2,
                     [f"no X server answers on DISPLAY=:{free}"])


def test_gui_without_a_display_in_a_fresh_process(tmp_path):
    """The command line as a person types it: no PyBullet crash ("cannot connect to X server", exit 1)."""
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    done = subprocess.run([sys.executable, "-m", "hil.cli", "walk", "--gui", "--seconds", "1", "--quiet"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    # one line; PyBullet not even imported (it prints its build time on import); a tree whose
    # compiled modules are stale says so first, which is not this verb's
    lines = [line for line in done.stderr.splitlines() if "compiled hot modules" not in line]
    assert len(lines) == 1 and "--gui needs a display: DISPLAY is not set" in lines[0], done.stderr


@pytest.mark.parametrize("argv,words,usage", [
    (["walk", "--seconds", "1", "--screenshot", "x.png"], ["--screenshot needs --gui"], False),
    (["walk", "--seconds", "1", "--gui-speed", "2"], ["--gui-speed needs --gui"], False),
    (["walk", "--seconds", "1", "--gui", "--gui-speed", "0"], ["--gui-speed", "positive"], True),
    (["learn", "--trials", "1", "--out", "{tmp}/run", "--screenshot", "x.png"], ["--screenshot needs --gui"], False),
])
def test_window_options_are_checked_first(tmp_path, capsys, argv, words, usage):
    one_line_refusal(capsys, [a.replace("{tmp}", str(tmp_path)) for a in argv], 2, words, usage)


def test_a_screenshot_not_png_or_unwritable_is_refused_before_the_walk(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DISPLAY", ":0")  # never reached: the file is checked first
    one_line_refusal(capsys, ["walk", "--gui", "--seconds", "1", "--screenshot", str(tmp_path / "x.jpg")], 2,
                     ["name it FILE.png"])
    (tmp_path / "a_file").write_text("mine")
    one_line_refusal(capsys, ["walk", "--gui", "--seconds", "1", "--screenshot", str(tmp_path / "a_file" / "x.png")],
                     3, ["--screenshot", "a_file"])


def test_pacing_sleeps_until_the_wall_clock_catches_up_and_never_sprints(monkeypatch):
    clock = {"now": 100.0}
    slept = []

    def fake_sleep(s):
        slept.append(s)
        clock["now"] += s

    class Time:  # the module's clock and sleep, and only the module's
        perf_counter = staticmethod(lambda: clock["now"])
        sleep = staticmethod(fake_sleep)

    monkeypatch.setattr(gui, "time", Time)
    view = gui.GuiView(gui.ViewConfig(speed=2.0))
    view.pace(10.0)  # the first call takes the clock
    clock["now"] += 0.1
    view.pace(10.5)  # 0.5 s simulated at speed 2 is 0.25 s of wall time; 0.1 s went by
    assert slept == [pytest.approx(0.15)]
    clock["now"] += 5.0  # a stall: 5 s behind
    view.pace(11.0)
    clock["now"] += 0.01
    view.pace(11.1)  # 0.05 s due, 0.01 s went by: no catching up on the stall
    assert slept[1:] == [pytest.approx(0.04)] and view.slept_s == pytest.approx(0.19)
    fast = gui.GuiView(gui.ViewConfig(speed=float("inf")))
    fast.pace(0.0)
    fast.pace(50.0)
    assert len(slept) == 2


def test_the_camera_turns_to_a_far_obstacle_and_back(monkeypatch):
    class Plant:
        dt_s = 0.001
        carriage_x_m = 10.0
        obstacles: list = []

        class _p:  # noqa: N801 - the bullet client's place
            calls: list = []

            @classmethod
            def resetDebugVisualizerCamera(cls, *args):  # noqa: N802 - PyBullet's name
                cls.calls.append(args)

    class Ls:
        plant = Plant()

    from firmware_sim.plant import Obstacle

    config = gui.ViewConfig(smoothing_s=0.0)
    view = gui.GuiView(config)
    view.follow(Ls)
    assert Plant._p.calls[-1][:3] == (config.near.distance_m, config.near.yaw_deg, config.near.pitch_deg)
    assert Plant._p.calls[-1][3] == [10.0 + config.near.ahead_m, 0.0, config.near.height_m]
    Plant.obstacles = [Obstacle(10.0 + 2.8)]
    view.follow(Ls)
    assert Plant._p.calls[-1][1] == config.far.yaw_deg
    Plant.obstacles = [Obstacle(10.0 + (config.near_gap_m + config.far_gap_m) / 2)]
    view.follow(Ls)
    assert Plant._p.calls[-1][1] == pytest.approx((config.near.yaw_deg + config.far.yaw_deg) / 2)
    smooth = gui.GuiView(gui.ViewConfig(smoothing_s=0.3))
    Plant.obstacles = []
    smooth.follow(Ls)
    Plant.obstacles = [Obstacle(10.0 + 2.8)]
    smooth.follow(Ls)  # 16 ms later: turned a little, not all the way
    assert config.far.yaw_deg < Plant._p.calls[-1][1] < config.near.yaw_deg
