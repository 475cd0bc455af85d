"""The bad-input table: every mistake a person can make on the command lines that we answer, as data.

Each :class:`Row` is one command with a mistake in it: its argv (``{tmp}`` stands for a scratch
folder, :func:`setup_files` puts there the files the rows need), the exit code it must end with
(:mod:`controller.errors`' table), the key words its message must hold, and how it is run:
``inprocess`` (``main(argv)``, fast), ``subprocess`` (``python -m hil.cli``/``controller.cli``:
where the verb changes process state, installs signal handlers or must not share this process),
``script`` (the installed console script) or ``sigint`` (a SIGINT sent while the verb starts).
``keep`` names files of the scratch folder that must be left exactly as they were (a command
that refuses must not have deleted or changed anything).

:mod:`tests.test_bad_inputs` runs every row and asserts no traceback, the exit code and the key
words; ``python3 -m tests.test_bad_inputs --markdown > docs/errors.md`` writes the table as the
code prints it. ``owner`` marks the rows whose behaviour another part of the project builds
(the leg's verbs, ``learn`` and ``sweep``).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path

HARNESS = "elegant-stepping"
LEG = "elegant-stepping-leg"


@dataclass(frozen=True)
class Row:
    """One bad input.

    Attributes:
        name: a short unique id (the test's id).
        mistake: what is wrong, for the table.
        argv: the command's arguments after the program; ``{tmp}`` is the scratch folder.
        code: the exit code it must end with.
        words: key words the message on stderr must hold (``{tmp}`` expanded).
        prog: the program: :data:`HARNESS` or :data:`LEG`.
        how: ``inprocess``, ``subprocess``, ``script`` or ``sigint``.
        keep: scratch files that must be unchanged afterwards.
        hide: modules made to look not installed (a missing extra).
        owner: who builds the behaviour, if not the command-line layer (for the report).
    """

    name: str
    mistake: str
    argv: tuple[str, ...]
    code: int
    words: tuple[str, ...]
    prog: str = HARNESS
    how: str = "inprocess"
    keep: tuple[str, ...] = ()
    hide: tuple[str, ...] = ()
    owner: str = ""

    def expand(self, tmp: Path) -> tuple[list[str], list[str]]:
        """(argv, words) with ``{tmp}`` replaced by ``tmp``."""
        t = str(tmp)
        return [a.replace("{tmp}", t) for a in self.argv], [w.replace("{tmp}", t) for w in self.words]


# -- the files the rows read ------------------------------------------------------------------------
FRAMES = 6000  # three BLF containers of python-can's writer (about 2730 frames each)


def session_frames(n: int = FRAMES) -> list:
    """Frames shaped like a session's: each 2 ms tick the controller's Set_Input_Pos to both axes,
    the axes' encoder estimates back, a heartbeat now and then (the replay ticks on them)."""
    import can

    from protocol import BusContract

    c = BusContract.load()
    out = []
    t = 1000.0
    while len(out) < n:
        for node in (0, 1):
            out.append(can.Message(timestamp=t, arbitration_id=c.odrive_id(node, "Set_Input_Pos"),
                                   data=struct.pack("<fhh", 0.0, 0, 0), is_extended_id=False))
        for node in (0, 1):
            out.append(can.Message(timestamp=t + 2e-4, arbitration_id=c.odrive_id(node, "Get_Encoder_Estimates"),
                                   data=struct.pack("<ff", 0.0, 0.0), is_extended_id=False))
        t += 2e-3
    return out[:n]


def write_blf(path: Path, frames: list) -> bytes:
    import can

    with can.Logger(str(path)) as log:
        for m in frames:
            log.on_message_received(m)
    return path.read_bytes()


def write_candump(path: Path, frames: list, junk_at_line: int | None = None) -> None:
    lines = [f"({m.timestamp:.6f}) vcan0 {m.arbitration_id:03X}#{bytes(m.data).hex().upper()}" for m in frames]
    if junk_at_line is not None:
        lines[junk_at_line - 1] = "hi there, this is not a frame"
    path.write_text("\n".join(lines) + "\n")


def learn_metrics(trials: int = 3) -> dict:
    """A small but well-formed learn ``metrics.json``."""
    return {
        "config": {"trials": trials, "seed": 0, "obstacle_height_m": 0.08, "obstacle_depth_m": 0.10,
                   "range_noise_m": 0.02, "learning": True},
        "trials": [{"index": i, "success": bool(i % 2), "start_distance_m": 2.0, "obstacle_height_m": 0.08,
                    "reflexes": [], "footfalls_m": [-0.9, -0.6, -0.3], "burst_s": [0.3], "gated_range_m": [],
                    "gated_cells": [], "modulation_s": [0.0], "gated_decisions": 0, "lift_steps": 0, "sim_s": 5.0}
                   for i in range(trials)],
        "summary": {"trials": trials, "success_rate": 0.33, "wall_s": 1.0, "sim_s": 15.0, "trials_per_minute": 180.0},
    }


def setup_files(tmp: Path) -> None:
    """Every file the rows read, in ``tmp`` (a few hundred kilobytes, well under a second)."""
    tmp.mkdir(parents=True, exist_ok=True)
    frames = session_frames()
    whole = write_blf(tmp / "whole.blf", frames)
    (tmp / "empty.blf").write_bytes(b"")
    (tmp / "garbage.blf").write_bytes(bytes((i * 7919 + 13) % 256 for i in range(4096)))
    (tmp / "truncated.blf").write_bytes(whole[: len(whole) * 2 // 3])
    flipped = bytearray(whole)
    flipped[len(whole) // 2] ^= 0x10  # a bit in the second container's compressed data
    (tmp / "bitflip.blf").write_bytes(bytes(flipped))
    import can.io.blf as blf  # a writer that never closed its file: the header counts no data

    w = blf.BLFWriter(str(tmp / "unclosed.blf"))
    for m in frames:
        w.on_message_received(m)
    w._flush()
    w.file.flush()
    w.file.close()
    write_candump(tmp / "junk.log", frames[:20], junk_at_line=8)
    (tmp / "bus.xyz").write_text("(1.0) vcan0 00C#00\n")
    future = tmp / "future"  # a session folder from a newer elegant-stepping
    future.mkdir()
    write_blf(future / "bus.blf", frames[:100])
    (future / "bus.blf.json").write_text(json.dumps({"format": "bus-log", "format_version": 99,
                                                     "project_version": "9.9", "frames": 100}))
    other = tmp / "other"  # metadata of another kind beside a log
    other.mkdir()
    write_blf(other / "bus.blf", frames[:100])
    (other / "bus.blf.json").write_text(json.dumps({"format": "walk", "format_version": 1}))
    short = tmp / "short"  # a log cut at a frame boundary: its metadata counts more
    short.mkdir()
    write_blf(short / "bus.blf", frames[:1000])
    (short / "bus.blf.json").write_text(json.dumps({"format": "bus-log", "format_version": 1, "frames": 1200}))
    (tmp / "records.jsonl").write_text('[1, 2, 3]\n{"kind": "step", "index": 0}\n')
    (tmp / "a_file").write_text("a file, not a folder\n")
    (tmp / "not.json").write_text("{this is not json\n")
    (tmp / "scenario.txt").write_text("precious notes, not a socket\n")
    for name, data in (("wrong_list", []), ("wrong_types", {"config": {"seed": "zero"}, "trials": "many",
                                                               "summary": 3})):
        (tmp / name).mkdir()
        (tmp / name / "metrics.json").write_text(json.dumps(data))
    traced = learn_metrics()
    traced["trials"][0]["trace"] = {"t_s": ["a", "b"], "foot_x_m": [0.0, 1.0], "foot_z_m": [0.0, 0.0]}
    traced["trials"][-1]["trace"] = {"t_s": [0.0, 1.0], "foot_x_m": [0.0, 1.0], "foot_z_m": [0.0, 0.0]}
    (tmp / "bad_trace").mkdir()
    (tmp / "bad_trace" / "metrics.json").write_text(json.dumps(traced))
    (tmp / "bad_weights").mkdir()
    (tmp / "bad_weights" / "metrics.json").write_text(json.dumps(learn_metrics()))
    (tmp / "bad_weights" / "weights.npz").write_bytes(b"PK\x03\x04 this is not a zip archive at all")
    import numpy as np

    from controller.stepping.weights import save_weights

    (tmp / "context_no_beams").mkdir()  # a row of weights per height context, and no beams that bound them
    (tmp / "context_no_beams" / "metrics.json").write_text(json.dumps(learn_metrics()))
    save_weights(tmp / "context_no_beams" / "weights.npz", np.zeros((4, 28)), 0.04, generations=1)
    (tmp / "invalid.toml").write_text("[axes.knee]\ngear_ratio = -6\n")
    (tmp / "wrong_types.toml").write_text('[axes.knee]\ngear_ratio = "six"\n[bus]\nbitrate = "fast"\n')
    (tmp / "deep.toml").write_text("x = " + "[" * 500 + "]" * 500 + "\n")
    (tmp / "not_toml.toml").write_text("[bus\nchannel = \n")
    (tmp / "unit.service").write_text("[Service]\nExecStart=/bin/true\n")
    (tmp / "experiment_unknown_key.toml").write_text("rail_speed_m_s = 0.6\nrail_sped_m_s = 0.4\n")
    (tmp / "experiment_wrong_type.toml").write_text('range_dropout = "often"\n')
    (tmp / "experiment_bad_height.toml").write_text("obstacle_heights_m = [0.06, 0.55]\n")


# -- the rows ----------------------------------------------------------------------------------------
ROWS: tuple[Row, ...] = (
    # buses that cannot be opened
    Row("fwsim_interface_nosuch", "an interface python-can does not know",
        ("firmware-sim", "--interface", "nosuch", "--seconds", "1"), 4, ("cannot open the CAN bus", "nosuch")),
    Row("fwsim_channel_can9", "a CAN channel that does not exist (the likeliest deployment mistake)",
        ("firmware-sim", "--interface", "socketcan", "--channel", "can9", "--seconds", "1"), 4,
        ("cannot open the CAN bus", "can9")),
    Row("mitm_channel_can9", "the man-in-the-middle on channels that do not exist",
        ("mitm", "--controller-channel", "can9", "--leg-channel", "can8", "--seconds", "1"), 4,
        ("--controller-channel can9", "cannot open the CAN bus")),
    Row("mitm_bad_spec", "a fault spec with an unknown fault", ("mitm", "--to-leg", "gremlins=0.5"), 2,
        ("--to-leg", "gremlins")),
    Row("mitm_rate_above_one", "a fault rate above 1", ("mitm", "--from-leg", "drop=2"), 2, ("--from-leg", "drop")),
    Row("mitm_same_channels", "the same channel on both sides",
        ("mitm", "--controller-channel", "vcan0", "--leg-channel", "vcan0"), 2, ("must differ",)),
    # damaged logs
    Row("decode_empty_blf", "decode an empty .blf", ("decode", "{tmp}/empty.blf"), 3, ("empty.blf", "frame 1", "empty")),
    Row("decode_garbage_blf", "decode a file of garbage named .blf", ("decode", "{tmp}/garbage.blf"), 3,
        ("garbage.blf", "frame 1", "not a BLF file")),
    Row("decode_truncated_blf", "decode a .blf cut short (a kill, a full disk)", ("decode", "{tmp}/truncated.blf"), 3,
        ("truncated.blf", "frame 2731", "truncated", "--partial")),
    Row("decode_bitflip_blf", "decode a .blf with one bit flipped", ("decode", "{tmp}/bitflip.blf"), 3,
        ("bitflip.blf", "frame 2731", "zlib")),
    Row("decode_unclosed_blf", "decode a .blf whose writer never closed it", ("decode", "{tmp}/unclosed.blf"), 3,
        ("unclosed.blf", "never closed")),
    Row("decode_truncated_partial", "decode a truncated .blf with --partial: the valid frames, a warning",
        ("decode", "{tmp}/truncated.blf", "--partial"), 0, ("warning", "read 2730 frames", "frame 2731")),
    Row("decode_junk_line", "decode a candump log with a junk line", ("decode", "{tmp}/junk.log"), 3,
        ("junk.log", "line 8", "hi there")),
    Row("decode_junk_line_partial", "the same with --partial", ("decode", "{tmp}/junk.log", "--partial"), 0,
        ("warning", "read 7 frames", "line 8")),
    Row("decode_missing", "decode a log that does not exist", ("decode", "{tmp}/nothere.blf"), 3,
        ("nothere.blf", "no such log")),
    Row("decode_unknown_format", "decode a file of a format python-can does not read", ("decode", "{tmp}/bus.xyz"), 3,
        ("bus.xyz", "not a bus log format")),
    Row("decode_load_truncated", "the bus load of a truncated .blf", ("decode", "{tmp}/truncated.blf", "--load"), 3,
        ("truncated.blf", "frame 2731")),
    Row("decode_limit_negative", "a negative --limit", ("decode", "{tmp}/whole.blf", "--limit", "-1"), 2, ("--limit",)),
    Row("replay_empty_blf", "replay an empty .blf", ("replay", "{tmp}/empty.blf"), 3, ("empty.blf", "frame 1")),
    Row("replay_garbage_blf", "replay garbage named .blf", ("replay", "{tmp}/garbage.blf"), 3,
        ("garbage.blf", "not a BLF file")),
    Row("replay_truncated_blf", "replay a truncated .blf (was: replayed in part, exit 0)",
        ("replay", "{tmp}/truncated.blf"), 3, ("truncated.blf", "frame 2731", "--partial")),
    Row("replay_bitflip_blf", "replay a .blf with one bit flipped", ("replay", "{tmp}/bitflip.blf"), 3,
        ("bitflip.blf", "frame 2731")),
    Row("replay_truncated_partial", "replay a truncated .blf with --partial: the valid frames, a warning",
        ("replay", "{tmp}/truncated.blf", "--partial"), 0, ("warning", "read 2730 frames", "frame 2731")),
    Row("replay_junk_line", "replay a candump log with a junk line", ("replay", "{tmp}/junk.log"), 3,
        ("junk.log", "line 8")),
    Row("replay_metadata_future", "replay a session recorded by a newer version (bus-log metadata version 99)",
        ("replay", "{tmp}/future/bus.blf"), 3, ("bus.blf.json", "format version 99", "9.9")),
    Row("replay_metadata_other_kind", "replay a log whose metadata file is another kind of file",
        ("replay", "{tmp}/other/bus.blf"), 3, ("bus.blf.json", "not a bus-log file")),
    Row("replay_log_shorter_than_metadata", "replay a log cut at a frame boundary (its metadata counts more)",
        ("replay", "{tmp}/short/bus.blf"), 3, ("frame 1001", "metadata counts 1200")),
    Row("replay_records_missing", "replay with --records that do not exist",
        ("replay", "{tmp}/whole.blf", "--records", "{tmp}/nothere.jsonl"), 3, ("--records", "no such file")),
    Row("replay_records_garbage", "replay with records that are not the controller's",
        ("replay", "{tmp}/whole.blf", "--records", "{tmp}/records.jsonl"), 3, ("--records", "records.jsonl")),
    Row("replay_config_missing", "replay with a --config that does not exist",
        ("replay", "{tmp}/whole.blf", "--config", "{tmp}/nothere.toml"), 3, ("--config", "nothere.toml")),
    Row("replay_json_under_file", "replay with --json under a file",
        ("replay", "{tmp}/whole.blf", "--json", "{tmp}/a_file/out.json"), 3, ("--json", "a_file", "not a folder")),
    # files of the wrong structure
    Row("analyze_wrong_structure", "analyze a metrics.json that is a list", ("analyze", "{tmp}/wrong_list"), 3,
        ("wrong_list",), owner="A"),
    Row("analyze_wrong_types", "analyze a metrics.json with fields of the wrong types", ("analyze", "{tmp}/wrong_types"),
        3, ("wrong_types",), owner="A"),
    Row("analyze_not_a_folder", "analyze a folder that does not exist", ("analyze", "{tmp}/nothere"), 3, ("nothere",)),
    Row("analyze_garbage_weights", "analyze a run whose weights.npz is garbage", ("analyze", "{tmp}/bad_weights"), 3,
        ("weights.npz",)),
    Row("analyze_json_is_folder", "analyze with --json naming a folder", ("analyze", "{tmp}/bad_weights", "--json", "{tmp}"),
        3, ("--json", "a folder, not a file")),
    Row("figures_wrong_structure", "figures from a metrics.json that is a list",
        ("figures", "{tmp}/wrong_list", "--out", "{tmp}/figs"), 3, ("wrong_list",), owner="A"),
    Row("figures_bad_trace", "figures from a run whose trace holds words, not numbers",
        ("figures", "{tmp}/bad_trace", "--out", "{tmp}/figs"), 3, ("trials[0].trace.t_s", "not a list of numbers")),
    Row("figures_context_no_beams", "figures from a run whose weights have a row per height context and whose "
        "config names no beams", ("figures", "{tmp}/context_no_beams", "--out", "{tmp}/figs"), 3,
        ("controller.height.beam_heights_m",)),
    Row("figures_out_under_file", "figures with --out under a file",
        ("figures", "{tmp}/bad_trace", "--out", "{tmp}/a_file/figs"), 3, ("--out", "a_file", "not a folder")),
    Row("compare_missing", "compare with a file that does not exist (was exit 2)",
        ("compare", "{tmp}/nothere.json", "{tmp}/not.json"), 3, ("nothere.json", "no such file")),
    Row("compare_not_json", "compare a file that is not JSON", ("compare", "{tmp}/not.json", "{tmp}/not.json"), 3,
        ("not.json", "not valid JSON")),
    # output paths
    Row("walk_json_under_file", "walk with --json under a file (refused before walking)",
        ("walk", "--seconds", "1", "--json", "{tmp}/a_file/walk.json"), 3, ("--json", "a_file", "not a folder")),
    Row("killsave_folder_is_file", "killsave with --folder naming a file",
        ("killsave", "--kills", "1", "--folder", "{tmp}/a_file"), 3, ("--folder", "a file, not a folder")),
    Row("bench_json_under_file", "bench with --json under a file (refused before measuring)",
        ("bench", "--json", "{tmp}/a_file/bench.json"), 3, ("--json", "a_file")),
    Row("animate_out_is_file", "animate with --out naming a file", ("animate", "--out", "{tmp}/a_file"), 3,
        ("--out", "a file, not a folder")),
    Row("faults_json_under_file", "the fault matrix with --json under a file (refused before any case)",
        ("faults", "--only", "none", "--json", "{tmp}/a_file/rows.json", "--out", "{tmp}/faults"), 3, ("--json", "a_file")),
    Row("hil_out_under_file", "hil with --out under a file (refused before User-Mode Linux boots)",
        ("hil", "--trials", "1", "--out", "{tmp}/a_file/hil"), 3, ("--out", "a_file", "not a folder")),
    Row("dryrun_out_under_file", "the dry run with --out under a file",
        ("dryrun", "--out", "{tmp}/a_file/dryrun"), 3, ("--out", "a_file")),
    # bad options
    Row("faults_only_gremlins", "the fault matrix with --only a row that does not exist (was: an empty table, exit 0)",
        ("faults", "--only", "gremlins", "--out", "{tmp}/faults"), 2, ("--only", "gremlins", "known:", "drop")),
    Row("faults_bad_seeds", "the fault matrix with --seeds that are not seeds", ("faults", "--seeds", "0-x"), 2,
        ("--seeds", "0-x")),
    Row("faults_negative_seed", "the fault matrix with a negative seed", ("faults", "--seeds", "-5"), 2, ("--seeds",)),
    Row("hil_trials_0", "hil --trials 0 (refused before User-Mode Linux boots)",
        ("hil", "--trials", "0", "--out", "{tmp}/hil"), 2, ("--trials", "positive")),
    Row("hil_silence_without_trial", "hil --silence-node without --silence-at-trial",
        ("hil", "--silence-node", "3", "--out", "{tmp}/hil"), 2, ("--silence-node", "--silence-at-trial")),
    Row("hil_sim_kill", "hil --clock sim with a kill -9 (a wall-clock measurement)",
        ("hil", "--clock", "sim", "--kill-controller-at-trial", "1", "--out", "{tmp}/hil"), 2,
        ("--kill-controller-at-trial", "--clock wall")),
    Row("hil_grace_on_the_wall_clock", "hil --grace-s without --clock sim",
        ("hil", "--grace-s", "5", "--out", "{tmp}/hil"), 2, ("--grace-s", "--clock sim")),
    Row("leg_run_sim_clock_on_a_real_bus", "the leg's daemon on simulated time on a CAN bus that is not virtual",
        ("run", "--clock", "sim", "--interface", "socketcan", "--channel", "can0", "--socket", "none"), 2,
        ("--clock sim", "can0", "not a virtual one"), prog=LEG),
    Row("fwsim_sim_without_scenario", "firmware-sim --clock sim without the side channel",
        ("firmware-sim", "--clock", "sim"), 2, ("--clock sim", "--scenario")),
    Row("mitm_sim_silence_after", "mitm --clock sim with a wall-clock silence",
        ("mitm", "--clock", "sim", "--silence-after-s", "1"), 2, ("--silence-after-s", "--clock sim")),
    Row("walk_seed_negative", "a negative --seed", ("walk", "--seed", "-5"), 2, ("--seed", "non-negative")),
    Row("walk_seed_word", "a --seed that is not a number", ("walk", "--seed", "one"), 2, ("--seed", "'one'")),
    Row("walk_burst_out_of_bounds", "a burst length outside the CPG's bounds", ("walk", "--burst-s", "9"), 2,
        ("--burst-s", "burst_s")),
    Row("animate_trials_0", "animate --trials 0", ("animate", "--trials", "0", "--out", "{tmp}/anim"), 2, ("--trials",)),
    Row("killsave_kills_0", "killsave --kills 0", ("killsave", "--kills", "0"), 2, ("--kills",)),
    Row("fwsim_dropout_2", "a probability above 1", ("firmware-sim", "--range-dropout-prob", "2"), 2,
        ("--range-dropout-prob",)),
    Row("dryrun_seconds_0", "the dry run for 0 seconds", ("dryrun", "--seconds", "0", "--out", "{tmp}/dryrun"), 2,
        ("--seconds",)),
    Row("dryrun_unit_missing", "the dry run with a unit file that does not exist",
        ("dryrun", "--unit", "{tmp}/nothere.service", "--out", "{tmp}/dryrun"), 3, ("--unit", "no such file")),
    Row("unknown_verb", "a verb that does not exist", ("gremlins",), 2, ("invalid choice", "gremlins")),
    # files that are not ours
    Row("fwsim_scenario_not_a_socket", "firmware-sim --scenario naming a file (was: deleted it)",
        ("firmware-sim", "--scenario", "{tmp}/scenario.txt", "--seconds", "1"), 3,
        ("--scenario", "scenario.txt", "not a socket", "left alone"), keep=("scenario.txt",)),
    # the process
    Row("missing_extra", "a verb whose extra is not installed", ("walk", "--seconds", "1"), 6,
        ("needs pybullet", "pip install"), hide=("pybullet",)),
    Row("sigint_at_startup", "SIGINT (Ctrl-C) while the verb starts", ("walk", "--seconds", "1000", "--quiet",
                                                                          "--json", "{tmp}/walk.json"), 130,
        ("interrupted",), how="sigint"),
    Row("console_script", "the installed console script, on a truncated log", ("decode", "{tmp}/truncated.blf"), 3,
        ("frame 2731",), how="script"),
    # the leg's verbs (built by the leg's side of the project)
    Row("leg_run_channel_can9", "the daemon on a CAN channel that does not exist",
        ("run", "--interface", "socketcan", "--channel", "can9", "--seconds", "1", "--socket", "none"), 4, ("can9",),
        prog=LEG, how="subprocess", owner="C2"),
    Row("leg_run_interface_nosuch", "the daemon on an interface python-can does not know",
        ("run", "--interface", "nosuch", "--channel", "x", "--seconds", "1", "--socket", "none"), 4, ("nosuch",),
        prog=LEG, how="subprocess", owner="C2"),
    Row("leg_run_config_missing", "the daemon with a --config that does not exist",
        ("run", "--config", "{tmp}/nothere.toml", "--seconds", "1", "--socket", "none"), 3, ("nothere.toml",),
        prog=LEG, how="subprocess", owner="C2"),
    Row("leg_config_invalid", "config check on an invalid configuration (was exit 2)",
        ("config", "check", "{tmp}/invalid.toml"), 3, ("gear_ratio",), prog=LEG, owner="C2"),
    Row("leg_config_wrong_types", "config check on a TOML of the wrong types",
        ("config", "check", "{tmp}/wrong_types.toml"), 3, ("gear_ratio",), prog=LEG, owner="C2"),
    Row("leg_config_nested_500", "config check on a TOML nested 500 deep", ("config", "check", "{tmp}/deep.toml"), 3,
        ("deep.toml", "nested"), prog=LEG, owner="C2"),
    Row("leg_config_not_toml", "config check on a file that is not TOML", ("config", "check", "{tmp}/not_toml.toml"), 3,
        ("not_toml.toml",), prog=LEG, owner="C2"),
    Row("leg_config_missing", "config check on a file that does not exist", ("config", "check", "{tmp}/nothere.toml"),
        3, ("nothere.toml",), prog=LEG, owner="C2"),
    # learn and sweep (built by the experiments' side of the project)
    Row("learn_out_empty", "learn --out '' (was: wrote into the current folder)", ("learn", "--trials", "1", "--out", ""),
        3, ("--out",), owner="A"),
    Row("learn_out_is_file", "learn --out naming a file (refused before any trial)",
        ("learn", "--trials", "1", "--out", "{tmp}/a_file"), 3, ("--out", "a_file"), keep=("a_file",), owner="A"),
    Row("learn_seed_negative", "learn --seed -5", ("learn", "--seed", "-5", "--out", "{tmp}/learn"), 2, ("--seed",),
        owner="A"),
    Row("learn_start_reversed", "learn --start-m 3,2 (MIN above MAX)",
        ("learn", "--start-m", "3,2", "--out", "{tmp}/learn"), 2, ("--start-m", "MIN must not exceed MAX")),
    Row("learn_heights_bad_value", "learn --obstacle-heights-m with a height out of range",
        ("learn", "--obstacle-heights-m", "0.06,0.55", "--out", "{tmp}/learn"), 2,
        ("--obstacle-heights-m", "0.55", "[0.03, 0.5] m")),
    Row("learn_height_beyond_the_leg", "learn with an obstacle taller than the leg can clear at all",
        ("learn", "--obstacle-heights-m", "0.06,0.25", "--out", "{tmp}/learn"), 3,
        ("0.250 m is above the leg's 0.223 m limit", "knee")),
    Row("learn_experiment_unknown_key", "an experiment TOML with an unknown key (a typo)",
        ("learn", "--experiment", "{tmp}/experiment_unknown_key.toml", "--out", "{tmp}/learn"), 3,
        ("experiment_unknown_key.toml", "rail_sped_m_s", "unknown key")),
    Row("learn_experiment_wrong_type", "an experiment TOML with a value of the wrong type",
        ("learn", "--experiment", "{tmp}/experiment_wrong_type.toml", "--out", "{tmp}/learn"), 3,
        ("experiment_wrong_type.toml", "range_dropout", "not a string")),
    Row("learn_experiment_missing", "learn --experiment naming no file",
        ("learn", "--experiment", "{tmp}/nothere.toml", "--out", "{tmp}/learn"), 3, ("nothere.toml", "no such file")),
    Row("sweep_experiment_bad_height", "a sweep's experiment TOML with a height out of range",
        ("sweep", "--experiment", "{tmp}/experiment_bad_height.toml", "--out", "{tmp}/sweep", "--quiet"), 3,
        ("experiment_bad_height.toml", "obstacle_heights_m", "0.55")),
    Row("sweep_other_configuration", "a sweep into a folder of another configuration (nothing deleted)",
        ("sweep", "--out", "{tmp}/sweep", "--seeds", "0", "--methods", "none", "--trials", "2", "--quiet"), 3,
        ("{tmp}/sweep",), keep=("sweep/summary.json",), owner="A"),
    Row("sweep_into_a_folder_of_other_things", "a sweep into a folder of other files (--out /tmp; nothing written)",
        ("sweep", "--out", "{tmp}", "--seeds", "0", "--methods", "none", "--trials", "1", "--quiet"), 3,
        ("not a sweep's folder", "a_file"), keep=("a_file",)),
    # the window (issue 19; --gui without a display: tests/hil/experiments/test_gui.py, which controls DISPLAY)
    Row("walk_screenshot_without_gui", "walk --screenshot without --gui (there is no window to take it of)",
        ("walk", "--seconds", "1", "--screenshot", "{tmp}/w.png"), 2, ("--screenshot needs --gui",)),
    # the course (issue 19)
    Row("course_gap_too_close", "course --gap-m with a minimum closer than the leg recovers from",
        ("course", "--gap-m", "0.3,2", "--out", "{tmp}/course"), 2, ("--gap-m", "0.6 m")),
    Row("course_height_beyond_the_leg", "course --heights-m with a height the leg cannot clear",
        ("course", "--heights-m", "0.04,0.3", "--out", "{tmp}/course"), 2, ("--heights-m", "limit")),
    Row("course_out_is_file", "course --out naming a file (refused before any obstacle)",
        ("course", "--obstacles", "2", "--out", "{tmp}/a_file"), 3, ("--out", "a_file"), keep=("a_file",)),
)
"""Every bad input, in the order of the table."""


def sweep_setup(tmp: Path) -> None:
    """A finished one-trial sweep in ``tmp/sweep`` (for the row that sweeps into it with another
    configuration); run only by that row."""
    from hil.cli import main

    rc = main(["sweep", "--out", str(tmp / "sweep"), "--seeds", "0", "--methods", "none", "--trials", "1",
               "--workers", "1", "--quiet"])
    if rc != 0 or not (tmp / "sweep" / "summary.json").exists():
        raise RuntimeError(f"the one-trial sweep the row needs did not finish (exit {rc})")


SETUPS = {"sweep_other_configuration": sweep_setup}
"""Rows that need more than :func:`setup_files` (run before the row, in its scratch folder)."""
