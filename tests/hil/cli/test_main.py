"""The command line: walk and bench write the documented JSON; bad input gets a clear error."""

from __future__ import annotations

import json

import pytest

from hil.cli import main

WALK_KEYS = {"steps", "footfalls_m", "stride_m", "burst_s", "swing_clearance_min_m", "commands_outside_limits",
             "frames_tx", "frames_rx", "late_ticks", "sim_s", "wall_s"}


def test_walk_writes_the_documented_keys(tmp_path):
    out = tmp_path / "walk.json"
    assert main(["walk", "--seconds", "4", "--seed", "2", "--burst-s", "0.35", "--json", str(out), "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert WALK_KEYS <= data.keys()
    assert data["steps"] >= 3 and all(b == pytest.approx(0.35) for b in data["burst_s"])
    assert data["frames_tx"]["Set_Input_Pos"] > 0 and data["frames_rx"]["Get_Encoder_Estimates"] > 0


def test_walk_to_stdout_is_pure_json(capfd):
    assert main(["walk", "--seconds", "1.5", "--quiet"]) == 0
    out = capfd.readouterr().out
    assert json.loads(out)["sim_s"] == pytest.approx(1.5)


@pytest.mark.parametrize("argv", [["walk", "--seconds", "-1"], ["walk", "--burst-s", "nan"], ["walk", "--seconds", "x"]])
def test_bad_arguments_exit_with_usage_error(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_burst_outside_the_cpg_bounds_is_a_clear_error(capsys):
    assert main(["walk", "--seconds", "1", "--burst-s", "3.0", "--quiet"]) == 2
    assert "burst_s" in capsys.readouterr().err


def test_bench_reports_each_figure_beside_its_reference(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "--seconds", "2", "--learn-trials", "2", "--json", str(out)]) == 0
    b = json.loads(out.read_text())
    assert b["lockstep_rtf"] > 0 and not {"bare_physics_rtf", "lockstep_vs_bare"} & b.keys()
    assert b["stack_us_per_step"] > 0 and b["floor_us_per_step"] > 0 and b["floor_queries_us_per_step"] > 0
    assert b["stack_vs_floor"] > 0 and b["stack_vs_floor_queries"] > 0
    assert b["detail"]["physics_floor"]["replay_exact"] is True and len(b["detail"]["physics_floor"]["pairs"]) >= 3
    assert b["detail"]["lockstep"]["walking"] is True
    assert b["tick_cost_us"]["p99"] >= b["tick_cost_us"]["median"] > 0
    assert {"encode", "decode", "cantools_encode", "cantools_decode"} <= b["codec_us"].keys()
    load = b["bus_load"]
    # 2 axes x (Set_Input_Pos + encoder) at 500 Hz dominate: about 2000 frames/s of ~110-130 bits
    assert load["frames_per_s_by_message"]["Set_Input_Pos"] == pytest.approx(1000, rel=0.01)
    assert 100 < load["bits_per_frame"] < 135
    assert load["fraction"] == pytest.approx(load["frames_per_s"] * load["bits_per_frame"] / 1e6)
    assert b["learning"]["trials"] == 2 and b["learning"]["trials_per_minute"] > 0
