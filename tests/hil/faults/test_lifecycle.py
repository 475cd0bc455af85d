"""The fault matrix's lifecycle rows, run as the matrix runs them: each must hold."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.faults import lifecycle


@pytest.mark.parametrize("name,errors", [("estop_latched_at_start", ["hip: ESTOP_REQUESTED", "knee: ESTOP_REQUESTED"]),
                                         ("driver_error_latched_at_start", ["knee: DRV_FAULT"])])
def test_a_fault_latched_at_start_is_never_cleared_and_never_armed(name, errors, tmp_path):
    row = lifecycle.ROWS[name](tmp_path)
    assert row["armed"] is False and row["phase"] == "inactive"
    assert row["clear_errors_sent"] == 0 and "Set_Axis_State" not in row["frames_sent"]
    assert all(e in row["refused"] for e in errors)
    assert row["commands_outside_limits"] == 0 and row["data_lost"] is False


def test_a_second_master_is_a_latched_fault_in_the_first_tick(tmp_path):
    row = lifecycle.ROWS["second_master"](tmp_path)
    assert row["ticks_to_fault"] == 1
    assert row["safe_state_ms"] is not None and row["safe_state_ms"] < 10
    assert "another master on the bus: id 0x00c" in row["fault_cause"]
    assert row["commands_outside_limits"] == 0


@pytest.mark.parametrize("name,cause", [("over_temperature", "hip motor temperature 90."),
                                        ("bus_undervoltage", "bus voltage 14.9 V below 18 V")])
def test_a_health_bound_crossed_while_walking_stops_the_leg_within_a_read_period(name, cause, tmp_path):
    row = lifecycle.ROWS[name](tmp_path)
    assert cause in row["fault_cause"] and row["bound_crossed_s"] is not None
    # the reading comes at most one read period (0.1 s) after the crossing, the fault in the tick
    # that drains it, every axis IDLE in the physics step after
    assert row["safe_state_ms"] is not None and row["safe_state_ms"] <= row["read_period_s"] * 1e3 + 10
    assert row["detect_ms"] <= row["safe_state_ms"]
    assert row["commands_outside_limits"] == 0 and row["data_lost"] is False


@pytest.mark.slow
def test_the_daemon_rows_keep_every_weights_file_and_stop_in_order(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative --out, as a person types it
    rows = lifecycle.run_rows(["restart_without_walking", "weights_incompatible", "sighup", "sigusr1"], Path("rows"))
    restart, incompatible, hup, usr1 = rows
    assert restart["files_unchanged"] and restart["phases"] == ["inactive", "inactive"] and restart["exit_codes"] == [0, 0]
    assert restart["weights_sources"] == ["file", "file"]  # the daemon read the very file that must not change
    assert incompatible["set_aside_intact"] and not incompatible["written_in_its_place"]
    assert incompatible["reported"] and incompatible["weights_source"] == "zeros"
    for row, name in ((hup, "SIGHUP"), (usr1, "SIGUSR1")):
        assert row["walked"] and row["exit_code"] == 0 and row["stopped_by"] == name and row["weights_source"] == "file"
        assert row["axes_idle"] and row["watchdog_trips"] == 0 and row["commands_checked"] > 0
    assert all(r["commands_outside_limits"] == 0 and r["data_lost"] is False for r in rows)
    assert (tmp_path / "rows" / "sighup" / "row.json").exists()  # read back by the next run


def test_an_unknown_row_name_is_an_error_with_the_known_ones(tmp_path, capsys):
    from hil.cli import main

    assert main(["faults", "--only", "gremlins", "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "unknown fault(s) gremlins" in err and "second_master" in err and "Traceback" not in err
