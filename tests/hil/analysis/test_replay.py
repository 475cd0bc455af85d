"""``replay``: a damaged log is refused (exit 3) or, with --partial, replayed up to the damage; the
files beside the log are checked for their structure; the frames its recorder lost are reported,
and a replay of a log with any lost is not called "as live"."""

from __future__ import annotations

import json
from array import array

import pytest

from hil.analysis.replay import replay, summary_tail
from hil.cli import main
from tests.bad_inputs import session_frames, write_blf


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    data = write_blf(d / "whole.blf", session_frames(6000))
    (d / "cut").mkdir()
    (d / "cut" / "bus.blf").write_bytes(data[: len(data) * 2 // 3])
    return d


def test_a_truncated_log_is_exit_3_and_with_partial_the_frames_before_the_damage(logs, capsys):
    assert main(["replay", str(logs / "cut" / "bus.blf")]) == 3
    err = capsys.readouterr().err
    assert err.splitlines() == [f"elegant-stepping replay: error: {logs}/cut/bus.blf: damaged at frame 2731: "
                                f"the file ends inside a container ({err.split('container (')[1].split(')')[0]}); "
                                f"the 2730 frames before it are valid (--partial: use them)"]
    assert main(["replay", str(logs / "cut" / "bus.blf"), "--partial", "--json", str(logs / "cut.json")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"elegant-stepping replay: warning: {logs}/cut/bus.blf: read 2730 frames, stopped at "
                             f"frame 2731: ")
    partial = json.loads((logs / "cut.json").read_text())
    assert partial["partial"]["frames_read"] == 2730 and partial["partial"]["stopped_at"] == "frame 2731"
    # the same decisions as a replay of the whole log's first 2730 frames
    first = replay(logs / "whole.blf", frames=session_frames(6000)[:2730])
    assert partial["steps"] == json.loads(json.dumps(first["steps"])) and partial["ticks"] == first["ticks"] > 0
    assert main(["replay", str(logs / "whole.blf"), "--json", str(logs / "whole.json")]) == 0
    assert json.loads((logs / "whole.json").read_text())["partial"] is None


def test_records_with_a_step_of_the_wrong_structure_are_named(logs, tmp_path, capsys):
    rec = tmp_path / "controller.jsonl"
    clock = json.dumps({"kind": "clock", "realtime_minus_monotonic_s": 1.5}) + "\n"
    rec.write_text(clock + json.dumps({"kind": "step", "index": 0, "cell": 3}) + "\n")
    assert main(["replay", str(logs / "whole.blf"), "--records", str(rec)]) == 3
    err = capsys.readouterr().err
    assert err.strip() == f"elegant-stepping replay: error: --records {rec}: step record 1 lacks modulation_s, burst_s"
    rec.write_text(clock + json.dumps({"kind": "step", "index": "zero", "cell": 3, "modulation_s": 0.0, "burst_s": 0.3}) + "\n")
    assert main(["replay", str(logs / "whole.blf"), "--records", str(rec)]) == 3
    assert "step record 1 has a field of the wrong type" in capsys.readouterr().err


def test_a_ticks_file_cut_short_is_named(tmp_path, capsys):
    write_blf(tmp_path / "bus.blf", session_frames(200))
    (tmp_path / "controller.jsonl").write_text(json.dumps({"kind": "clock", "realtime_minus_monotonic_s": 1.5}) + "\n")
    ticks = array("d", [0.0, 2.0, 0.002, 2.0]).tobytes()
    (tmp_path / "controller.ticks").write_bytes(ticks[:-3])
    assert main(["replay", str(tmp_path / "bus.blf")]) == 3
    err = capsys.readouterr().err
    assert "controller.ticks: 29 bytes, not whole (tick clock, frames read) pairs of doubles (cut short at tick 2)" in err
    (tmp_path / "controller.jsonl").write_text(json.dumps({"kind": "clock"}) + "\n")
    (tmp_path / "controller.ticks").write_bytes(ticks)
    assert main(["replay", str(tmp_path / "bus.blf")]) == 3
    assert "its clock record has no realtime_minus_monotonic_s" in capsys.readouterr().err


def _session(folder, metadata: dict | None, records: bool = True):
    """A short recorded session in ``folder``: its log, the recorder's metadata (None: none), and
    live records (one step, which the replay of these frames does not reach)."""
    folder.mkdir(exist_ok=True)
    write_blf(folder / "bus.blf", session_frames(400))
    if metadata is not None:
        (folder / "bus.blf.json").write_text(json.dumps({"format": "bus-log", "format_version": 1,
                                                         "project_version": "0.9", "frames": 400, **metadata}))
    if records:
        (folder / "controller.jsonl").write_text(
            json.dumps({"kind": "clock", "realtime_minus_monotonic_s": 1.5}) + "\n"
            + json.dumps({"kind": "step", "index": 0, "cell": 3, "modulation_s": 0.0, "burst_s": 0.3}) + "\n")
    return folder / "bus.blf"


def _run(log, capsys):
    assert main(["replay", str(log), "--json", str(log.parent / "replay.json")]) == 0
    err = capsys.readouterr().err.splitlines()
    return err, json.loads((log.parent / "replay.json").read_text())


def test_a_log_whose_recorder_lost_frames_is_replayed_but_not_called_as_live(tmp_path, capsys):
    log = _session(tmp_path / "lossy", {"frames_lost": 5})
    err, result = _run(log, capsys)
    assert err[0] == (f"elegant-stepping replay: warning: {log}: the recorder lost 5 frames (dropped by the kernel, "
                      f"its receive queue full): the replayed controller cannot read what the live one read, so this "
                      f"replay is not the live run")
    assert len(err) == 2 and "as live" not in err[1]
    assert err[1].endswith("; 0/0 steps match the live records (not a reproduction: 5 frames lost)")
    assert (result["frames_lost"], result["as_live"]) == (5, False)
    assert result["compared_steps"] == 0 and result["records"].endswith("controller.jsonl")  # compared all the same
    assert summary_tail(29, 37, 1, True) == "; 29/37 steps match the live records (not a reproduction: 1 frame lost)"
    assert summary_tail(29, 37, 8, True) == "; 29/37 steps match the live records (not a reproduction: 8 frames lost)"
    log = _session(tmp_path / "lossy_no_records", {"frames_lost": 1}, records=False)
    err, result = _run(log, capsys)
    assert "the recorder lost 1 frame (dropped" in err[0] and err[1].endswith("; 1 frame lost by the recorder")
    assert (result["frames_lost"], result["as_live"]) == (1, False)


def test_a_log_whose_recorder_lost_none_is_replayed_as_before(tmp_path, capsys):
    log = _session(tmp_path / "whole", {"frames_lost": 0})
    err, result = _run(log, capsys)
    assert len(err) == 1 and "warning" not in err[0]
    assert err[0].startswith("replayed 400 frames in ") and err[0].endswith("; 0/0 steps as live")
    assert (result["frames_lost"], result["as_live"]) == (0, True)
    assert summary_tail(37, 37, 0, True) == "; 37/37 steps as live" and summary_tail(None, None, 0, False) == ""


@pytest.mark.parametrize("metadata", [None, {}, {"frames_lost": None}],
                         ids=["no metadata", "metadata before the count", "not SocketCAN"])
def test_a_log_whose_lost_frames_are_unknown_is_reported_as_unknown(tmp_path, capsys, metadata):
    log = _session(tmp_path / "s", metadata)
    err, result = _run(log, capsys)
    assert len(err) == 1 and "warning" not in err[0]
    assert err[0].endswith("; 0/0 steps as live; frames lost by the recorder: unknown")
    assert (result["frames_lost"], result["as_live"]) == (None, None)


def test_a_simulated_time_log_replays_tick_for_tick_on_its_sync_frames():
    """A ``hil --clock sim`` log: replay ticks once per sync, on the frames before it, and so
    reproduces every decision of the live controller (here the in-process synced lockstep,
    recorded by a third node on its bus, as the recorder on vcan0 is)."""
    import math

    from controller.supervisor import Phase
    from hil.analysis.replay import replay
    from hil.lockstep.harness import LockstepConfig
    from hil.lockstep.synced import SyncedLockstep

    with SyncedLockstep(LockstepConfig(seed=3)) as ls:
        tap = ls.observer()
        frames = []
        try:
            while ls.loop.phase is not Phase.WALK or ls.t_s < 8.0:
                assert ls.t_s < 20.0
                ls.step()
                while (m := tap.recv(timeout=0.0)) is not None:
                    m.timestamp = float(len(frames))  # the recording's order
                    frames.append(m)
        finally:
            tap.shutdown()
        live = [(s.onset_s, s.cell, s.modulation_s, None if math.isnan(s.burst_s) else s.burst_s)
                for s in ls.loop.stats.steps]
        config, ticks = ls.config.controller, ls.loop.stats.ticks
    result = replay("in-memory", config, frames=frames)
    assert result["tick_source"] == "sync frames" and result["ticks"] == ticks
    got = [(s["onset_s"], s["cell"], s["modulation_s"], s["burst_s"]) for s in result["steps"]]
    assert len(live) > 5 and got == live  # every step, bit for bit
