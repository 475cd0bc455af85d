"""The animation: GIFs of the first and the last trial, rendered in DIRECT mode."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from hil.analysis.animation import AnimationConfig, FrameGrabber, label_frames, side_by_side
from hil.cli import main


def gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as img:
        out = []
        for i in range(img.n_frames):
            img.seek(i)
            out.append(np.asarray(img.convert("RGB")))
        return out


def test_animate_writes_before_and_after_gifs_of_moving_frames(tmp_path, capsys):
    out = tmp_path / "anim"
    summary = tmp_path / "animate.json"
    argv = ["animate", "--trials", "2", "--seed", "1", "--out", str(out), "--fps", "5", "--width", "96",
            "--height", "64", "--json", str(summary), "--quiet"]
    assert main(argv) == 0
    result = json.loads(summary.read_text())
    assert result["trials"] == 2 and set(result["success"]) == {"before", "after"}
    for name, width in (("before", 96), ("after", 96), ("before_after", 2 * 96 + 6)):
        path = out / f"{name}.gif"
        assert path.stat().st_size > 0
        frames = gif_frames(path)
        assert len(frames) > 1 and len(frames) == result["files"][name]["frames"]
        assert frames[0].shape == (64 + 30, width, 3)  # the rendered image under a 30 px header
        assert any(not np.array_equal(frames[0], f) for f in frames[1:])
        # the picture itself moves, not only the header's clock
        assert any(not np.array_equal(frames[0][30:], f[30:]) for f in frames[1:])
    assert "before.gif" in capsys.readouterr().err


def test_animate_needs_two_trials(tmp_path):
    assert main(["animate", "--trials", "1", "--out", str(tmp_path), "--quiet"]) == 2


@pytest.mark.parametrize("kwargs", [{"fps": 0.5}, {"width_px": 8}, {"lead_m": -1.0}])
def test_animation_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        AnimationConfig(**kwargs)


def test_frames_are_labelled_and_clips_are_put_side_by_side():
    grabber = FrameGrabber(AnimationConfig(fps=10, width_px=40, height_px=32), physics_hz=1000)
    assert grabber.every == 100
    grabber.frames = [np.full((32, 40, 3), 200, np.uint8), np.full((32, 40, 3), 100, np.uint8)]
    grabber.t_s, grabber.touching = [0.1, 0.2], [False, True]
    frames = label_frames(grabber, "before", success=False)
    assert [f.size for f in frames] == [(40, 62), (40, 62)]
    a, b = np.asarray(frames[0]), np.asarray(frames[1])
    assert (a[31, 0] == 200).all() and tuple(b[31, 0]) == (220, 0, 0)  # red border while touching
    both = side_by_side(frames, frames[:1], gap_px=2)
    assert len(both) == 2 and both[0].size == (82, 62)
    assert np.array_equal(np.asarray(both[1])[:, 42:], a)  # the shorter clip holds its last frame
    with pytest.raises(ValueError):
        side_by_side(frames, [])
