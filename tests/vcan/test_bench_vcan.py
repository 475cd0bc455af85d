"""``bench --hil`` on a real vcan0 (User-Mode Linux where the kernel has no CAN): each HIL figure
beside its floor."""

from __future__ import annotations

import json
import math

import pytest

from hil.bench.socketcan import FIGURES


def test_bench_hil_reports_each_figure_beside_its_floor(vcan_place, tmp_path):
    from hil.cli import main

    out = tmp_path / "bench.json"
    rc = main(["bench", "--hil", "--hil-seconds", "2", "--seconds", "1", "--learn-trials", "1", "--json", str(out)])
    h = json.loads(out.read_text())["hil"]
    assert rc == 0, h.get("error")
    assert h["available"] and h["ran"] and h["where"] == vcan_place
    if vcan_place == "uml":
        assert h["uml"]["exit_code"] == 0 and 0 < h["uml"]["boot_to_session_s"] < h["uml"]["wall_s"]
    assert set(h["figures"]) == set(FIGURES)
    for name, fig in h["figures"].items():
        assert fig["hil"] is not None and fig["floor"] is not None, name
        if fig["floor"] > 0:
            assert fig["ratio"] == pytest.approx(fig["hil"] / fig["floor"]), name
        assert fig["excess"] == pytest.approx(fig["hil"] - fig["floor"]), name
    d = h["detail"]
    hil, loop, echo = d["hil"], d["floor_loop"], d["floor_echo"]
    assert hil["error"] is None and hil["exit_codes"] == {"controller": 0, "firmware_sim": 0}
    assert "walk" in hil["phases"] and hil["watchdog_trips"] == 0
    assert hil["ticks"]["ticks"] > 0 and loop["ticks"] > 0
    assert all(math.isfinite(x) and x >= 0 for x in (hil["ticks"]["span_s"], loop["span_s"]))
    j = loop["period_jitter_us"]
    assert 0 <= j["median"] <= j["p99"] <= j["max"]
    assert hil["command_to_feedback_us"]["n"] > 0 and echo["command_to_feedback_us"]["n"] > 0
    assert echo["answered"] > 0 and echo["sender"]["sent"] > 0
