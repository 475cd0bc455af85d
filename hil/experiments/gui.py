"""A person watching: PyBullet's window on a run, the camera following the carriage, real time.

``walk --gui`` and ``learn --gui`` (docs/gui.md) run their lockstep through ``WatchedLockstep``
(:func:`watched_harness`), a :class:`~hil.lockstep.harness.Lockstep` whose plant is in PyBullet's
GUI mode and whose ``step`` hands every physics step to a :class:`GuiView`, which

* points the window's camera at the carriage every :attr:`ViewConfig.camera_every_steps` physics
  steps (``resetDebugVisualizerCamera``: cheap), from behind and beside the leg, looking ahead
  along the rail: the leg large in the foreground (:attr:`ViewConfig.near`). While a learning
  trial's obstacle is far ahead, the camera turns further behind the leg and looks further ahead
  (:attr:`ViewConfig.far`), so the obstacle is in view from the moment it is placed; it comes
  back as the obstacle nears, smoothly;
* paces the run so that simulated time never runs ahead of the wall clock (times ``speed``): it
  sleeps, and nothing else;
* saves a screenshot (``--screenshot FILE.png``) when the run ends, rendered with the window's
  own size and projection and the camera as last set (``getCameraImage`` with
  ``ER_BULLET_HARDWARE_OPENGL``), and measures from its segmentation mask how much of the frame
  is the leg (:class:`Shot`). During learning trials the screenshot is the view when the foot
  first reaches the last trial's obstacle (each trial removes its obstacle when it ends), so it
  shows the leg at the obstacle.

The window changes no result: PyBullet's GUI mode runs the same physics as DIRECT, and every
call the view makes only reads the plant's state or moves the camera (tests/hil/experiments/test_gui.py
compares learn runs with and without it, record for record). Nor is it part of an experiment's
configuration: a learn run started with ``--gui`` and resumed without is the same run.

:func:`check_display` refuses ``--gui`` in one line where no window can open (no ``DISPLAY``,
no X server answering on it, no libX11 or libGL): PyBullet itself would print "cannot connect to
X server" and end the process. PyBullet's window thread prints on the C level's stdout; while the
window is open that goes to stderr, so ``walk --json -`` stays JSON.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

log = logging.getLogger(__name__)


def check_display(option: str = "--gui") -> None:
    """Refuse ``option`` in one line where PyBullet's window cannot open.

    Raises:
        UsageError: ``DISPLAY`` is not set, or no X server answers on it (exit 2).
        MissingDependency: libX11 or libGL cannot be loaded (exit 6).
    """
    from controller.errors import MissingDependency, UsageError

    display = os.environ.get("DISPLAY", "")
    if not display:
        raise UsageError(f"{option} needs a display: DISPLAY is not set; run under xvfb-run "
                         f"(xvfb-run -a -s '-screen 0 1280x1024x24' elegant-stepping ...) or on a desktop")
    libs = {}
    for name, package in (("X11", "libx11-6"), ("GL", "libgl1")):
        try:
            libs[name] = ctypes.CDLL(ctypes.util.find_library(name) or f"lib{name}.so.1")
        except OSError:
            raise MissingDependency(f"{option} needs lib{name}, which cannot be loaded here "
                                    f"(Debian: apt-get install {package} libgl1-mesa-dri)") from None
    x11 = libs["X11"]
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(display.encode())
    if not handle:
        raise UsageError(f"{option} needs a display: no X server answers on DISPLAY={display}; "
                         f"run under xvfb-run or start the X server")
    x11.XCloseDisplay(handle)


# -- the command line's options -------------------------------------------------------------

def add_arguments(p) -> None:
    """``--gui``, ``--gui-speed``, ``--screenshot``: the window's options, shared by ``walk`` and ``learn``."""
    import argparse

    def speed(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be a positive number (inf: not paced), got {text!r}")
        return value

    p.add_argument("--gui", action="store_true",
                   help="open PyBullet's window and run at real time, the camera following the carriage "
                        "(needs a display, xvfb-run's will do; changes no result; docs/gui.md)")
    p.add_argument("--gui-speed", type=speed, default=1.0, metavar="X",
                   help="with --gui: at most X simulated seconds per wall-clock second (default 1: real "
                        "time; inf: as fast as it runs)")
    p.add_argument("--screenshot", default=None, metavar="FILE.png",
                   help="with --gui: save the window's view as a PNG when the run ends (learn: when the "
                        "foot reaches the last trial's obstacle) and say how much of it is the leg")


def view_from(args) -> "GuiView | None":
    """The view the options ask for (None without ``--gui``), after checking them and the display:
    call it before any work. ``--gui-speed`` or ``--screenshot`` without ``--gui`` is a usage error."""
    from controller.cli.common import check_output_file
    from controller.errors import UsageError

    if not args.gui:
        given = [o for o, v in (("--screenshot", args.screenshot is not None), ("--gui-speed", args.gui_speed != 1.0))
                 if v]
        if given:
            raise UsageError(f"{given[0]} needs --gui (it is about the window)")
        return None
    check_output_file(args.screenshot, "--screenshot")
    if args.screenshot is not None and not str(args.screenshot).lower().endswith(".png"):
        raise UsageError(f"--screenshot {args.screenshot}: the file is a PNG; name it FILE.png")
    check_display("--gui")
    return GuiView(ViewConfig(speed=args.gui_speed, screenshot=args.screenshot))


# -- the view -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Camera:
    """The window's camera relative to the carriage: ``distance_m`` from its target, turned
    ``yaw_deg`` about the vertical (0: beside the leg, on its right, the -y side; -90: right behind it) and
    ``pitch_deg`` (negative: looking down); the target ``ahead_m`` ahead of the hip along the
    rail, ``height_m`` above the ground. PyBullet's window sees 90 degrees vertically."""

    distance_m: float
    yaw_deg: float
    pitch_deg: float
    ahead_m: float
    height_m: float

    def blend(self, other: "Camera", s: float) -> "Camera":
        """``self`` at ``s`` 0, ``other`` at ``s`` 1, in between linearly."""
        return Camera(*(a + (b - a) * s for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self) -> tuple[float, ...]:
        return self.distance_m, self.yaw_deg, self.pitch_deg, self.ahead_m, self.height_m


@dataclass(frozen=True)
class ViewConfig:
    """How the window shows a run.

    Attributes:
        speed: at most this many simulated seconds per wall-clock second (default 1: real time);
            ``math.inf`` does not pace. Pacing only sleeps: it changes no result.
        camera_every_steps: physics steps between camera moves (default 16: 60 Hz at 1 kHz).
        near: the camera walking, and with an obstacle close (the leg large, the next metre ahead in view).
        far: the camera while an obstacle is ``far_gap_m`` or more ahead of the hip (it is in view
            up to the sensor's 3 m); between ``near_gap_m`` and ``far_gap_m`` the two are blended.
        near_gap_m, far_gap_m: see ``far`` [m]; default 0.6 and 2.2.
        smoothing_s: the camera follows the blend with this time constant [s of simulated time];
            default 0.3 (a new obstacle does not make it jump).
        screenshot: a PNG file to save the window's view into when the run ends; None: none.
        shadows: PyBullet's shadows (default off: on a software renderer, such as Xvfb's, they cost
            more than the physics and the run falls behind real time).
    """

    speed: float = 1.0
    camera_every_steps: int = 16
    near: Camera = Camera(0.56, -18.0, -15.0, 0.22, 0.29)
    far: Camera = Camera(0.85, -48.0, -20.0, 0.50, 0.25)
    near_gap_m: float = 0.6
    far_gap_m: float = 2.2
    smoothing_s: float = 0.3
    screenshot: str | None = None
    shadows: bool = False

    def __post_init__(self) -> None:
        if not self.speed > 0:
            raise ValueError(f"speed must be above 0 (math.inf: not paced), got {self.speed}")
        if not 1 <= self.camera_every_steps <= 10000:
            raise ValueError(f"camera_every_steps must be in [1, 10000], got {self.camera_every_steps}")
        if not 0.0 <= self.near_gap_m < self.far_gap_m:
            raise ValueError(f"near_gap_m must be in [0, far_gap_m), got {self.near_gap_m} and {self.far_gap_m}")
        if not self.smoothing_s >= 0.0:
            raise ValueError(f"smoothing_s must be at least 0, got {self.smoothing_s}")


@dataclass
class Shot:
    """A screenshot and what its segmentation mask says: the fractions of the frame's pixels that
    are the leg (thigh, shank, foot), the whole rig (the leg, the carriage, the sensor's boom) and
    an obstacle, and the leg's bounding box as fractions of the frame (``x0, y0, x1, y1``, y
    down; None if no pixel is the leg)."""

    path: str
    width_px: int
    height_px: int
    t_s: float
    leg_fraction: float
    rig_fraction: float
    obstacle_fraction: float
    leg_box: tuple[float, float, float, float] | None

    def describe(self) -> str:
        box = "not in the frame" if self.leg_box is None else (
            f"{self.leg_box[2] - self.leg_box[0]:.0%} wide and {self.leg_box[3] - self.leg_box[1]:.0%} high")
        return (f"screenshot {self.path} ({self.width_px}x{self.height_px} px, t = {self.t_s:.2f} s): the leg is "
                f"{self.leg_fraction:.1%} of the pixels, {box}; the rig {self.rig_fraction:.1%}, an obstacle "
                f"{self.obstacle_fraction:.1%}")

    def as_dict(self) -> dict[str, Any]:
        return {"path": self.path, "size_px": [self.width_px, self.height_px], "t_s": self.t_s,
                "leg_fraction": self.leg_fraction, "rig_fraction": self.rig_fraction,
                "obstacle_fraction": self.obstacle_fraction,
                "leg_box": None if self.leg_box is None else list(self.leg_box)}


@dataclass
class GuiView:
    """The window's side of a run: camera, pacing, screenshot (see the module). ``shot``: the
    screenshot saved at the end (None before, or without ``config.screenshot``); ``slept_s``:
    the wall time spent pacing."""

    config: ViewConfig = field(default_factory=ViewConfig)
    shot: Shot | None = None
    steps: int = 0
    slept_s: float = 0.0
    camera: tuple | None = None  # (distance, yaw, pitch, target) as last set
    _blend: float | None = None  # 0 near .. 1 far, smoothed
    _wall0: float | None = None
    _sim0: float = 0.0
    _pending: tuple | None = None  # (rgb, seg, t_s) grabbed at the last obstacle's crossing
    _crossed: Any = None  # the obstacle whose crossing was grabbed

    def open(self, ls) -> None:
        """A clean window (no side panels, no keyboard shortcuts), the camera on the carriage."""
        import pybullet

        p = ls.plant._p
        p.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0)
        p.configureDebugVisualizer(pybullet.COV_ENABLE_KEYBOARD_SHORTCUTS, 0)
        p.configureDebugVisualizer(pybullet.COV_ENABLE_SHADOWS, int(self.config.shadows))
        self.follow(ls)

    def after_step(self, ls) -> None:
        """After every physics step: every ``camera_every_steps``, move the camera, grab the
        crossing (with a screenshot asked for) and pace."""
        self.steps += 1
        if self.steps % self.config.camera_every_steps:
            return
        self.follow(ls)
        if self.config.screenshot is not None:
            self._grab_crossing(ls)
        self.pace(ls.t_s)

    def follow(self, ls) -> None:
        """Point the camera at the carriage: near, far or between by the obstacle's distance ahead."""
        c, plant = self.config, ls.plant
        hip_x = plant.carriage_x_m
        goal = 0.0
        obstacles = plant.obstacles
        if obstacles:
            gap = obstacles[0].near_edge_x_m - hip_x
            goal = min(1.0, max(0.0, (gap - c.near_gap_m) / (c.far_gap_m - c.near_gap_m)))
        if self._blend is None or c.smoothing_s == 0.0:
            self._blend = goal
        else:
            dt = c.camera_every_steps * plant.dt_s
            self._blend += (goal - self._blend) * (1.0 - math.exp(-dt / c.smoothing_s))
        cam = c.near.blend(c.far, self._blend)
        target = [hip_x + cam.ahead_m, 0.0, cam.height_m]
        self.camera = (cam.distance_m, cam.yaw_deg, cam.pitch_deg, target)
        plant._p.resetDebugVisualizerCamera(cam.distance_m, cam.yaw_deg, cam.pitch_deg, target)

    def pace(self, t_s: float) -> None:
        """Sleep until the wall clock has caught up with simulated time (divided by ``speed``).
        Behind by more than a quarter second (a slow host, the window being dragged), the clock
        is taken anew rather than caught up by running fast."""
        if math.isinf(self.config.speed):
            return
        now = time.perf_counter()
        if self._wall0 is None:
            self._wall0, self._sim0 = now, t_s
            return
        ahead = (t_s - self._sim0) / self.config.speed - (now - self._wall0)
        if ahead > 0:
            time.sleep(ahead)
            self.slept_s += ahead
        elif ahead < -0.25:
            self._wall0, self._sim0 = now, t_s

    # -- the screenshot --------------------------------------------------------------------
    def _grab_crossing(self, ls) -> None:
        """During a trial: grab the view once, when the foot first reaches the obstacle's near edge."""
        plant = ls.plant
        obstacles = plant.obstacles
        if not obstacles or obstacles[0] is self._crossed:
            return
        if plant.foot_position()[0] >= obstacles[0].near_edge_x_m:
            self._crossed = obstacles[0]
            self._pending = (*self.render(ls), ls.t_s)

    def render(self, ls):
        """The window's view now: (rgb H x W x 3 uint8, segmentation H x W) as numpy arrays, with
        the window's size and projection and the camera as last set (the window takes a new
        camera at its next frame: its own view matrix may still be the one before)."""
        import numpy as np
        import pybullet

        p = ls.plant._p
        width, height, _, proj = p.getDebugVisualizerCamera()[:4]
        distance, yaw, pitch, target = self.camera
        view = p.computeViewMatrixFromYawPitchRoll(target, distance, yaw, pitch, 0.0, 2)
        _, _, rgb, _, seg = p.getCameraImage(width, height, view, proj, renderer=pybullet.ER_BULLET_HARDWARE_OPENGL,
                                             flags=pybullet.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX)
        rgb = np.asarray(rgb, dtype=np.uint8).reshape(height, width, -1)[:, :, :3].copy()
        seg = np.asarray(seg, dtype=np.int64).reshape(height, width)
        return rgb, seg

    def save_screenshot(self, ls) -> Shot:
        """Save the screenshot (the last trial's crossing if one was grabbed, else the view now)
        and measure it (:class:`Shot`, also in ``shot``)."""
        from PIL import Image

        if self._pending is not None:
            rgb, seg, t_s = self._pending
        else:
            rgb, seg = self.render(ls)
            t_s = ls.t_s
        path = Path(self.config.screenshot)
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rgb).save(path, format="PNG")
        self.shot = measure(seg, ls.plant, str(path), t_s)
        log.info("%s", self.shot.describe())
        return self.shot


def measure(seg, plant, path: str = "", t_s: float = 0.0) -> Shot:
    """What a segmentation mask (``ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX``: body id in the
    low 24 bits, link index + 1 above; -1 nothing) of ``plant``'s world shows (:class:`Shot`)."""
    import numpy as np

    seg = np.asarray(seg)
    hit = seg >= 0
    body = np.where(hit, seg & ((1 << 24) - 1), -1)
    link = np.where(hit, (seg >> 24) - 1, -2)
    rig = body == plant.robot
    leg = rig & np.isin(link, [plant.thigh_link, plant.shank_link, plant.foot_link])
    obstacle = hit & (body != plant.robot) & (body != plant.ground)
    height, width = seg.shape
    box = None
    if leg.any():
        ys, xs = np.nonzero(leg)
        box = tuple(round(float(v), 4) for v in (xs.min() / width, ys.min() / height, (xs.max() + 1) / width,
                                                 (ys.max() + 1) / height))
    n = float(width * height)
    return Shot(path, width, height, t_s, float(leg.sum() / n), float(rig.sum() / n), float(obstacle.sum() / n), box)


class _StdoutToStderr:
    """File descriptor 1 pointed at stderr until :meth:`restore` (PyBullet's window thread
    prints on it at any time, and on closing)."""

    def __init__(self) -> None:
        sys.stdout.flush()
        self._saved: int | None = os.dup(1)
        os.dup2(2, 1)

    def restore(self) -> None:
        if self._saved is not None:
            sys.stdout.flush()
            os.dup2(self._saved, 1)
            os.close(self._saved)
            self._saved = None


class WindowClosed(KeyboardInterrupt):
    """The person closed PyBullet's window: the run stops as if interrupted (``learn`` keeps its
    finished trials and resumes on the same command; exit 130)."""

    def __init__(self) -> None:
        super().__init__("the PyBullet window was closed")
        print("elegant-stepping: the PyBullet window was closed: stopping as if interrupted", file=sys.stderr)


def watched_harness(view: GuiView) -> Callable[..., Any]:
    """A harness factory for :class:`~hil.experiments.learn.LearningRun` and
    :func:`~hil.experiments.walk.run_walk`: a ``WatchedLockstep`` shown by ``view``."""
    return functools.partial(watched_lockstep_class(), view=view)


@functools.cache
def watched_lockstep_class() -> type:
    """``WatchedLockstep``, defined on first use: the harness (PyBullet, the controller) is
    imported only when a window is asked for, after :func:`check_display`."""
    from hil.lockstep.harness import Lockstep

    class WatchedLockstep(Lockstep):
        """:class:`~hil.lockstep.harness.Lockstep` in PyBullet's window, shown by a
        :class:`GuiView` after every physics step; closing saves the view's screenshot (if it
        asks for one) before the window goes."""

        def __init__(self, config, *, premotor=None, view: GuiView, **kwargs) -> None:
            self._stdout = _StdoutToStderr()
            try:
                super().__init__(config, premotor=premotor, gui=True, **kwargs)
                self.view = view
                view.open(self)
            except BaseException:
                self._stdout.restore()
                raise

        def step(self) -> bool:
            import pybullet

            try:
                ticked = super().step()
                self.view.after_step(self)
            except pybullet.error:
                if pybullet.isConnected(self.plant._p._client):
                    raise
                raise WindowClosed() from None
            return ticked

        def close(self) -> None:
            import pybullet

            try:
                if self.view.config.screenshot is not None and self.view.shot is None:
                    if pybullet.isConnected(self.plant._p._client):
                        self.view.save_screenshot(self)
                    else:
                        log.warning("no screenshot: the window was closed")
            finally:
                try:
                    super().close()
                finally:
                    self._stdout.restore()

    return WatchedLockstep
