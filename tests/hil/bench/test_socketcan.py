"""``bench --hil``: the HIL figures beside their floor.

The figure computations are checked on synthetic tick times; the session itself runs on a real
vcan0 (natively, else inside User-Mode Linux) and FAILS with what to install where neither can be
had (deselect on purpose with -m 'not vcan'). No timing threshold is asserted: only structure and
sanity.
"""

from __future__ import annotations

import json
import subprocess
from array import array
from pathlib import Path

import pytest

from hil.bench.socketcan import read_ticks, side_by_side, tick_figures
from controller.daemon.pacing import Pacer
from hil.uml.runner import VcanUnavailable

P = 0.002


def test_perfect_ticks_have_no_jitter_and_no_late_ticks():
    f = tick_figures([10.0 + k * P for k in range(1001)], P)
    assert f["ticks"] == 1001 and f["periods"] == 1000
    assert f["late_ticks"] == 0 and f["late_per_10k"] == 0.0
    assert f["period_jitter_us"]["median"] == pytest.approx(0.0, abs=1e-6)
    assert f["period_jitter_us"]["max"] == pytest.approx(0.0, abs=1e-6)
    assert f["span_s"] == pytest.approx(2.0)


def test_late_ticks_per_10k_and_nearest_rank_percentiles():
    # 1000 periods: 980 exact, 15 of +100 us (not late), 5 of 3 periods (late: above 1.5 periods)
    periods = [P] * 980 + [P + 100e-6] * 15 + [3 * P] * 5
    times = [0.0]
    for p in periods:
        times.append(times[-1] + p)
    f = tick_figures(times, P, late_factor=1.5)
    assert f["late_ticks"] == 5 and f["late_per_10k"] == pytest.approx(50.0)
    j = f["period_jitter_us"]
    assert j["median"] == pytest.approx(0.0, abs=1e-6)
    assert j["p99"] == pytest.approx(100.0, abs=1e-3)  # rank 990 of 1000 lies in the +100 us group
    assert j["max"] == pytest.approx(4000.0, abs=1e-3)
    assert f["max_period_us"] == pytest.approx(6000.0, abs=1e-3)


def test_the_figures_agree_with_the_pacers_own_count():
    class Clock:
        t = 50.0

        def __call__(self):
            return self.t

        def sleep(self, s):
            self.t += s + 30e-6

    c = Clock()
    pacer = Pacer(P, clock=c, sleep=c.sleep, late_factor=1.5)
    times = []
    for k in range(2000):
        times.append(pacer.wait())
        if k % 97 == 0:
            c.t += 0.0041  # an overrun: late, periods skipped
    ours, its = tick_figures(times, P, 1.5), pacer.summary()
    assert ours["late_ticks"] == its["late_ticks"] > 0
    assert ours["ticks"] == its["ticks"]
    for q in ("median", "p99"):  # the pacer keeps a 1 us histogram
        assert ours["period_jitter_us"][q] == pytest.approx(its["period_jitter_us"][q], abs=1.0)


def test_too_few_ticks_give_none_not_an_error():
    f = tick_figures([1.0], P)
    assert f["periods"] == 0 and f["late_per_10k"] is None and f["period_jitter_us"]["p99"] is None


def test_side_by_side_ratio_and_excess():
    assert side_by_side(300.0, 100.0) == {"hil": 300.0, "floor": 100.0, "ratio": 3.0, "excess": 200.0}
    assert side_by_side(5.0, 0.0)["ratio"] is None and side_by_side(5.0, 0.0)["excess"] == 5.0
    assert side_by_side(None, 1.0) == {"hil": None, "floor": 1.0, "ratio": None, "excess": None}


def test_read_ticks_reads_the_controllers_format_from_a_time_on(tmp_path):
    a = array("d", [1.0, 2.0, 1.002, 0.0, 1.004, 1.0])
    path = tmp_path / "c.ticks"
    path.write_bytes(a.tobytes() + b"\x00" * 5)  # a write cut short at the end is ignored
    assert read_ticks(path) == [1.0, 1.002, 1.004]
    assert read_ticks(path, since_s=1.001) == [1.002, 1.004]


def _cheap_bench(monkeypatch):
    import hil.bench.run as bench

    monkeypatch.setattr(bench, "bench_physics_floor", lambda s, seed=0, pairs=5: {"detail": {}})
    monkeypatch.setattr(bench, "bench_lockstep", lambda s, seed=0: {"rtf": 1.0, "tick_cost_us": {}})
    monkeypatch.setattr(bench, "bench_codec", lambda: {})
    monkeypatch.setattr(bench, "bench_bus_load", lambda s, seed=0: {})
    monkeypatch.setattr(bench, "bench_learning", lambda n, seed=0: {})


def test_without_vcan_the_hil_section_says_so_and_only_hil_fails(monkeypatch, tmp_path):
    import hil.uml.runner as uml
    from hil.cli import main

    _cheap_bench(monkeypatch)

    def nowhere(mode="auto", channel="vcan0"):
        raise VcanUnavailable(uml.instruction(channel))

    monkeypatch.setattr(uml, "where", nowhere)
    out = tmp_path / "b.json"
    assert main(["bench", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert list(written)[:3] == ["format", "format_version", "project_version"]  # the stamp comes first
    assert written["format"] == "bench" and written["format_version"] == 1 and written["project_version"]
    h = written["hil"]
    assert h["available"] is False and h["ran"] is False and "user-mode-linux" in h["install"]
    assert main(["bench", "--hil", "--hil-seconds", "1", "--json", str(out)]) != 0
    h = json.loads(out.read_text())["hil"]
    assert h["available"] is False and "apt-get install -y user-mode-linux kmod" in h["error"] + h["install"]


def test_the_session_file_is_stamped_and_read_back_without_the_stamp(tmp_path):
    from hil.bench.socketcan import SESSION_KIND, read_session, write_session

    path = tmp_path / "hil.json"
    write_session(path, {"available": True, "started_unix": 1.5})
    raw = json.loads(path.read_text())
    assert raw["format"] == SESSION_KIND == "bench-hil" and raw["format_version"] == 1 and raw["project_version"]
    assert read_session(path) == {"available": True, "started_unix": 1.5}


@pytest.mark.parametrize("content,words", [
    ({"format": "bench-hil", "format_version": 99, "project_version": "9.9"}, ["format version 99", "9.9"]),
    ({"format": "walk", "format_version": 1}, ["'walk' file", "not a bench-hil file"]),
    ({"available": True}, ["no 'format' stamp"]),
    ("[1, 2]", ["a JSON object expected"]),
    ("{truncated", ["not JSON"]),
])
def test_a_session_file_of_another_kind_or_version_is_refused_in_one_line(tmp_path, content, words):
    from controller.errors import InputError
    from hil.bench.socketcan import read_session

    path = tmp_path / "hil.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(InputError) as info:
        read_session(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and all(w in msg for w in words), msg


def test_bench_hil_from_user_mode_linux_refuses_a_session_file_of_another_version(monkeypatch):
    """The host's side reads what the VM wrote; a file of an unknown version gives no figures and
    one line saying why, never a misread."""
    import hil.profile
    import hil.uml.runner as uml
    from hil.bench.socketcan import run_hil_bench

    def fake_uml(argv, timeout_s, capture):  # noqa: ARG001
        out = argv[argv.index("--out") + 1]
        Path(out).write_text(json.dumps({"format": "bench-hil", "format_version": 99, "available": True}))
        return subprocess.CompletedProcess(argv, 0, stdout="", stderr="")

    monkeypatch.setattr(uml, "where", lambda mode="auto", channel="vcan0": "uml")
    monkeypatch.setattr(uml, "run_in_uml", fake_uml)
    monkeypatch.setattr(hil.profile, "current", lambda: hil.profile.NATIVE)
    h = run_hil_bench(1.0)
    assert h["available"] is False and h["ran"] is False and h["where"] == "uml"
    assert "format version 99" in h["error"] and "\n" not in h["error"]
