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
    assert "unknown row(s) gremlins" in err and "second_master" in err and "Traceback" not in err


# -- the files the rows keep: stamped, read back, refused when of another kind or version ------------
def test_a_finished_row_is_kept_stamped_and_read_back_without_the_stamp(tmp_path, monkeypatch):
    import json

    calls = []

    def row(out):
        calls.append(out)
        return lifecycle._row("second_master", "lockstep", safe_state_ms=4.0, commands_outside_limits=0,
                              data_lost=False)

    monkeypatch.setitem(lifecycle.ROWS, "second_master", row)
    first = lifecycle.run_rows(["second_master"], tmp_path)
    kept = json.loads((tmp_path / "second_master" / "row.json").read_text())
    assert list(kept)[:3] == ["format", "format_version", "project_version"]
    assert kept["format"] == lifecycle.ROW_KIND == "fault-row" and kept["format_version"] == lifecycle.ROW_VERSION == 1
    again = lifecycle.run_rows(["second_master"], tmp_path)  # read back, not run again
    assert len(calls) == 1 and again == first and "format" not in again[0]
    assert again[0]["safe_state_ms"] == 4.0


def test_a_row_kept_before_stamps_is_read_as_version_0(tmp_path):
    import json

    path = tmp_path / "row.json"
    path.write_text(json.dumps({"fault": "sighup", "data_lost": False}))
    assert lifecycle.read_row(path) == {"fault": "sighup", "data_lost": False}


@pytest.mark.parametrize("content,words", [
    ({"format": "fault-row", "format_version": 99, "project_version": "9.9", "fault": "sighup"},
     ["fault-row format version 99", "elegant-stepping 9.9", "use a matching elegant-stepping"]),
    ({"format": "walk", "format_version": 1, "fault": "sighup"}, ["a 'walk' file, not a fault-row file"]),
    ("{\"fault\": ", ["not a fault-row file (not JSON"]),
])
def test_a_kept_row_of_another_kind_or_version_is_refused_in_one_line(tmp_path, content, words):
    import json

    from controller.errors import InputError

    folder = tmp_path / "sighup"
    folder.mkdir()
    path = folder / "row.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(InputError) as info:
        lifecycle.run_rows(["sighup"], tmp_path)  # refused before anything runs
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg and all(w in msg for w in words), msg


def test_the_daemon_legs_report_is_stamped_and_checked(tmp_path):
    import json

    from controller.errors import InputError, stamp
    from hil.faults.daemonleg import REPORT_KIND, REPORT_VERSION, read_report

    path = tmp_path / "leg.json"
    assert read_report(path) == {}  # none: nothing reported
    path.write_text(json.dumps({**stamp(REPORT_KIND, REPORT_VERSION), "commands_outside_limits": 0}))
    assert read_report(path) == {"commands_outside_limits": 0}
    for bad in ({"commands_outside_limits": 0}, {"format": REPORT_KIND, "format_version": 2}):
        path.write_text(json.dumps(bad))
        with pytest.raises(InputError, match="leg.json"):
            read_report(path)
