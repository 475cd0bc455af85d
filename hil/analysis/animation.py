"""An animation of the leg before and after learning: GIFs from PyBullet's renderer.

A learning run goes trial after trial as ``learn`` does; during the first and the last trial the
plant's side camera (:meth:`firmware_sim.plant.RigPlant.render_rgb`, the tiny software renderer,
so DIRECT mode is enough) is grabbed at ``fps`` frames per simulated second while the obstacle is
within ``lead_m`` ahead of the hip. Each frame is labelled with the trial, the simulated time and
whether the leg is touching the obstacle (a red border while it does); the trial's outcome goes in
the header. Written with Pillow: ``before.gif``, ``after.gif`` and ``before_after.gif`` side by side.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from hil.experiments.learn import LearnConfig, LearningRun
from hil.lockstep.harness import Lockstep

log = logging.getLogger(__name__)

_HEADER_PX = 30
_BORDER_PX = 4


@dataclass(frozen=True)
class AnimationConfig:
    """How the frames are grabbed.

    Attributes:
        fps: frames per simulated second; default 15.
        width_px, height_px: rendered image size [px]; default 360 x 240 (a header is added above).
        lead_m: grab while the obstacle's near edge is at most this far ahead of the hip [m], and
            until the trial ends; default 1.6 (the last few approach steps and the crossing).
            None grabs the whole trial.
        camera_ahead_m: the camera looks at this far ahead of the hip [m]; default 0.3.
    """

    fps: float = 15.0
    width_px: int = 360
    height_px: int = 240
    lead_m: float | None = 1.6
    camera_ahead_m: float = 0.3

    def __post_init__(self) -> None:
        if not 1.0 <= self.fps <= 100.0:
            raise ValueError(f"fps must be in [1, 100] frames per simulated second, got {self.fps}")
        if not (32 <= self.width_px <= 1920 and 32 <= self.height_px <= 1080):
            raise ValueError(f"frame size must be within 32x32 .. 1920x1080 px, got {self.width_px}x{self.height_px}")
        if self.lead_m is not None and not 0.0 < self.lead_m <= 3.5:
            raise ValueError(f"lead_m must be in (0, 3.5] m or None, got {self.lead_m}")


class FrameGrabber:
    """``on_step`` for :meth:`LearningRun.trial`: renders every ``physics_hz / fps`` physics steps."""

    def __init__(self, config: AnimationConfig, physics_hz: float) -> None:
        self.config = config
        self.every = max(1, int(round(physics_hz / config.fps)))
        self.frames: list[np.ndarray] = []
        self.t_s: list[float] = []
        self.touching: list[bool] = []
        self.render_s = 0.0
        self._n = 0
        self._t0: float | None = None

    def __call__(self, ls: Lockstep) -> None:
        plant = ls.plant
        if self._t0 is None:
            self._t0 = ls.t_s
        self._n += 1
        if self._n % self.every:
            return
        c = self.config
        hip_x = plant.carriage_x_m
        obstacles = plant.obstacles
        if c.lead_m is not None and obstacles and obstacles[0].near_edge_x_m - hip_x > c.lead_m:
            return
        wall0 = time.perf_counter()
        rgb = np.asarray(plant.render_rgb(c.width_px, c.height_px, target_x_m=hip_x + c.camera_ahead_m),
                         dtype=np.uint8).reshape(c.height_px, c.width_px, -1)[:, :, :3]
        self.render_s += time.perf_counter() - wall0
        self.frames.append(rgb.copy())
        self.t_s.append(ls.t_s - self._t0)
        self.touching.append(plant.obstacle_contact())


def label_frames(grabber: FrameGrabber, title: str, success: bool) -> list[Image.Image]:
    """The grabbed frames with a header (title, outcome, simulated time) and a red border while
    the leg touches the obstacle."""
    out = []
    outcome = "cleared the obstacle" if success else "hit the obstacle"
    for rgb, t, touching in zip(grabber.frames, grabber.t_s, grabber.touching):
        h, w = rgb.shape[:2]
        img = Image.new("RGB", (w, h + _HEADER_PX), "white")
        img.paste(Image.fromarray(rgb), (0, _HEADER_PX))
        draw = ImageDraw.Draw(img)
        draw.text((4, 2), title, fill="black")
        draw.text((4, 15), f"t = {t:5.2f} s   {outcome}", fill=(0, 110, 0) if success else (180, 0, 0))
        if touching:
            draw.rectangle([0, _HEADER_PX, w - 1, h + _HEADER_PX - 1], outline=(220, 0, 0), width=_BORDER_PX)
            draw.text((w - 60, _HEADER_PX + 6), "CONTACT", fill=(220, 0, 0))
        out.append(img)
    return out


def side_by_side(left: list[Image.Image], right: list[Image.Image], gap_px: int = 6) -> list[Image.Image]:
    """Frames of two clips next to each other; the shorter clip holds its last frame."""
    if not left or not right:
        raise ValueError("side_by_side needs two clips with at least one frame each")
    n = max(len(left), len(right))
    w = left[0].width + gap_px + right[0].width
    h = max(left[0].height, right[0].height)
    out = []
    for i in range(n):
        img = Image.new("RGB", (w, h), "white")
        img.paste(left[min(i, len(left) - 1)], (0, 0))
        img.paste(right[min(i, len(right) - 1)], (left[0].width + gap_px, 0))
        out.append(img)
    return out


def write_gif(frames: list[Image.Image], path: Path, fps: float) -> Path:
    """An endlessly looping GIF playing at ``fps`` (real time when frames are ``fps`` per sim s)."""
    if len(frames) < 1:
        raise ValueError(f"{path}: no frames to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(round(1000.0 / fps)), loop=0)
    return path


def animate(config: LearnConfig, out: str | Path, anim: AnimationConfig = AnimationConfig(),
            progress: bool = False) -> dict[str, Any]:
    """Run ``config.trials`` learning trials, grabbing the first and the last; write
    ``before.gif``, ``after.gif`` and ``before_after.gif`` into ``out``. Returns the files, their
    frame counts and sizes, each trial's success, and the wall time spent rendering."""
    if config.trials < 2:
        raise ValueError(f"an animation before and after learning needs at least 2 trials, got {config.trials}")
    out = Path(out)
    wall0 = time.perf_counter()
    run = LearningRun(config)
    grabbers: dict[str, FrameGrabber] = {}
    trials: dict[str, dict[str, Any]] = {}
    bar = None
    try:
        run.bring_up()
        physics_hz = run.ls.config.rig.physics_hz
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=config.trials, unit="trial", desc="animate")
        for i in range(config.trials):
            key = "before" if i == 0 else ("after" if i == config.trials - 1 else None)
            grabber = FrameGrabber(anim, physics_hz) if key else None
            trial = run.trial(i, on_step=grabber)
            if key:
                grabbers[key], trials[key] = grabber, trial
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        run.close()
    n = config.trials
    titles = {"before": "before learning (trial 1)",
              "after": f"after {n - 1} trial{'s' if n > 2 else ''} of learning (trial {n})"}
    clips = {k: label_frames(grabbers[k], titles[k], trials[k]["success"]) for k in ("before", "after")}
    for k, clip in clips.items():
        if len(clip) < 2:
            raise RuntimeError(f"the {k} trial gave {len(clip)} frame(s); raise fps or lead_m")
    paths = {
        "before": write_gif(clips["before"], out / "before.gif", anim.fps),
        "after": write_gif(clips["after"], out / "after.gif", anim.fps),
        "before_after": write_gif(side_by_side(clips["before"], clips["after"]), out / "before_after.gif", anim.fps),
    }
    files = {}
    for k, p in paths.items():
        with Image.open(p) as img:
            files[k] = {"path": str(p), "frames": img.n_frames, "size_px": list(img.size), "bytes": p.stat().st_size}
    result = {
        "files": files,
        "success": {k: bool(trials[k]["success"]) for k in trials},
        "trials": n,
        "seed": config.seed,
        "render_wall_s": sum(g.render_s for g in grabbers.values()),
        "wall_s": time.perf_counter() - wall0,
    }
    log.info("animation: %s", result)
    return result
