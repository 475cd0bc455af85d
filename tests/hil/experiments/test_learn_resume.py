"""Runs that survive being stopped: the run folder's states, resume, the kill -9 and SIGTERM paths,
and whether PyBullet's in-memory save and restore is bit-exact for this plant."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from controller.errors import InputError
from controller.stepping.weights import read_weights
from hil.analysis.records import compare, read
from hil.cli import main
from hil.experiments import learn
from hil.experiments.journal import FolderLock, read_journal
from hil.experiments.learn import LearnConfig, NotReproduced, folder_state, learn_into
from hil.experiments.methods import DEFAULT_METHOD

REPO = Path(__file__).resolve().parents[3]
SEED, TRIALS = 5, 4
CONFIG = LearnConfig(trials=TRIALS, seed=SEED, trace_trials=(0, -1),
                     method=DEFAULT_METHOD)  # what `learn --trials 4 --seed 5` runs
ARGV = ["learn", "--trials", str(TRIALS), "--seed", str(SEED), "--no-figures", "--quiet"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted run of CONFIG."""
    out = tmp_path_factory.mktemp("reference") / "run"
    outcome = learn_into(CONFIG, out)
    assert outcome.status == "ran"
    return out


def _copy_prefix(reference: Path, out: Path, trials: int, torn: bytes = b"") -> None:
    """``out`` as a run stopped after ``trials`` trials: the record's header and first trials,
    then ``torn`` (a line cut by kill -9)."""
    out.mkdir(parents=True)
    lines = (reference / "trials.jsonl").read_bytes().split(b"\n")
    (out / "trials.jsonl").write_bytes(b"\n".join(lines[: trials + 1]) + b"\n" + torn)


def _same_records(a: Path, b: Path) -> None:
    result = compare(read(a), read(b))
    assert result["same"], result["first_difference"]


# ---- the folder's files -------------------------------------------------------------------------------------


def test_a_run_writes_the_record_the_weights_and_stamped_metrics(reference):
    assert sorted(p.name for p in reference.iterdir()) == [".lock", "metrics.json", "trials.jsonl", "weights.npz"]
    metrics = json.loads((reference / "metrics.json").read_text())
    assert (metrics["format"], metrics["format_version"]) == ("learn-metrics", 1)
    assert {"config", "trials", "summary"} <= metrics.keys() and metrics["weights_file"] == "weights.npz"
    j = read_journal(reference / "trials.jsonl")
    assert j.records == json.loads(json.dumps(metrics["trials"])) and not j.torn
    assert "trace" in j.records[0] and "trace" in j.records[-1] and "trace" not in j.records[1]
    read_weights(reference / "weights.npz")  # checksum verified


def test_the_weights_are_saved_every_few_trials(tmp_path, monkeypatch):
    saved = []
    real = learn.save_weights
    monkeypatch.setattr(learn, "CHECKPOINT_EVERY", 2)
    monkeypatch.setattr(learn, "save_weights", lambda path, w, width, generations: (
        saved.append((len(read_journal(path.parent / "trials.jsonl").records), generations)),
        real(path, w, width, generations=generations)))
    learn_into(LearnConfig(trials=3, seed=SEED), tmp_path / "run")
    assert saved == [(2, 1), (3, 1)]  # after trial 2 (its record already on disk) and at the end
    assert not list((tmp_path / "run").glob("weights.npz.*"))  # one generation: no .prev beside it


# ---- the folder's states ------------------------------------------------------------------------------------


def test_a_finished_run_of_the_same_configuration_is_not_run_again(reference, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main([*ARGV, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "already holds this finished run" in said and "success" in said and said.count("\n") == 1
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize("option,value,key", [("--trials", "5", "trials"), ("--seed", "6", "seed"),
                                               ("--obstacle-height-m", "0.07", "obstacle_height_m")])
def test_another_configuration_is_refused_naming_the_key(reference, tmp_path, capsys, option, value, key):
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    (out / "metrics.json").unlink()  # unfinished: the record's header is checked
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    options = {"--trials": str(TRIALS), "--seed": str(SEED), option: value}
    argv = [x for kv in options.items() for x in kv]
    assert main(["learn", *argv, "--no-figures", "--quiet", "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert f"unfinished run of another configuration ({key}:" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing touched


def test_a_finished_run_of_another_configuration_is_refused(reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    with pytest.raises(InputError, match=r"finished run of another configuration \(trials: 4 in the folder, 5 asked\)"):
        folder_state(out, LearnConfig(trials=5, seed=SEED, trace_trials=(0, -1)))
    with pytest.raises(InputError, match=r"\(controller\.learner\.learning_rate_s: 0\.3 in the folder, 0\.2 asked\)"):
        from dataclasses import replace

        ctl = replace(CONFIG.controller, learner=replace(CONFIG.controller.learner, learning_rate_s=0.2))
        folder_state(out, replace(CONFIG, controller=ctl))


def test_overwrite_clears_a_learn_run_but_never_other_files(reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    (out / "figures").mkdir()
    (out / "figures" / "learning_curve.png").write_bytes(b"png")
    (out / "weights.npz.prev").write_bytes((out / "weights.npz").read_bytes())
    other = LearnConfig(trials=5, seed=SEED)
    assert folder_state(out, other, overwrite=True).kind == "new"
    assert [p.name for p in out.iterdir()] == [".lock"]

    shutil.rmtree(out)
    shutil.copytree(reference, out)
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="also holds notes.txt, which a learn run does not write; not clearing it"):
        folder_state(out, other, overwrite=True)
    assert (out / "metrics.json").exists() and (out / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_folder_of_other_things_is_refused(tmp_path, overwrite):
    (tmp_path / "thesis.tex").write_text("precious")
    with pytest.raises(InputError, match="holds files that are not a learn run's \\(thesis.tex\\)"):
        folder_state(tmp_path, CONFIG, overwrite=overwrite)
    assert (tmp_path / "thesis.tex").read_text() == "precious"


def test_a_finished_run_whose_weights_do_not_verify_is_refused(reference, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    data = (out / "weights.npz").read_bytes()
    (out / "weights.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="does not verify .*weights.npz"):
        folder_state(out, CONFIG)
    (out / "weights.npz").unlink()
    with pytest.raises(InputError, match="no such weights file"):
        folder_state(out, CONFIG)


def test_a_finished_folder_of_before_stamps_counts_as_finished(tmp_path):
    paper = dataclasses.replace(CONFIG, method="paper")  # the only learner with weights before stamps
    reference = tmp_path / "reference"
    learn_into(paper, reference)
    out = tmp_path / "old"
    out.mkdir()
    metrics = json.loads((reference / "metrics.json").read_text())
    old = {k: metrics[k] for k in ("config", "trials", "summary")}  # as learn wrote it before this version
    (out / "metrics.json").write_text(json.dumps(old))
    shutil.copy(reference / "weights.npz", out / "weights.npz")
    outcome = learn_into(paper, out)
    assert outcome.status == "finished" and outcome.metrics["trials"] == old["trials"]
    (out / "weights.npz").unlink()  # a method with weights (paper) whose weights are gone: not finished
    with pytest.raises(InputError, match="does not verify .*no such weights file"):
        learn_into(paper, out)


def test_a_locked_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    with FolderLock(out):
        assert main([*ARGV, "--out", str(out)]) == 3
    assert "another run is writing this folder" in capsys.readouterr().err
    assert not (out / "trials.jsonl").exists()


# ---- resume -------------------------------------------------------------------------------------------------


def test_a_run_stopped_mid_write_resumes_to_the_same_records(reference, tmp_path, caplog):
    out = tmp_path / "stopped"
    _copy_prefix(reference, out, 2, torn=b'{"index": 2, "success": fal')
    outcome = learn_into(CONFIG, out)
    assert (outcome.status, outcome.kept) == ("resumed", 2)
    assert "incomplete" in caplog.text  # the torn line was dropped, with a warning
    _same_records(reference, out)
    assert (out / "trials.jsonl").read_bytes() == (reference / "trials.jsonl").read_bytes().replace(
        json.dumps(read_journal(reference / "trials.jsonl").config).encode(),
        json.dumps(read_journal(out / "trials.jsonl").config).encode())
    assert read_weights(out / "weights.npz")[0].tobytes() == read_weights(reference / "weights.npz")[0].tobytes()


def test_a_kept_trial_that_does_not_reproduce_is_named(reference, tmp_path, capsys):
    out = tmp_path / "tampered"
    _copy_prefix(reference, out, 2)
    lines = (out / "trials.jsonl").read_text().splitlines()
    record = json.loads(lines[2])
    record["start_distance_m"] += 1e-12
    lines[2] = json.dumps(record)
    (out / "trials.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(NotReproduced, match=r"re-run of kept trial 1 differs \(trial 1\.start_distance_m: "):
        learn_into(CONFIG, out)
    assert main([*ARGV, "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert "does not reproduce here" in err and "--overwrite" in err and "Traceback" not in err
    assert len(read_journal(out / "trials.jsonl").records) == 2  # kept as it was


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def _records_on_disk(path: Path) -> int:
    try:
        return max(0, path.read_bytes().count(b"\n") - 1)
    except FileNotFoundError:
        return 0


def _start_and_wait(out: Path, trials_on_disk: int) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-m", "hil.cli", *ARGV, "--out", str(out)], env=_env(), cwd=REPO,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300.0  # generous: an outcome, not a timing
    while _records_on_disk(out / "trials.jsonl") < trials_on_disk:
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < deadline, "the run never wrote its trials"
        time.sleep(0.02)
    return p


def test_a_real_run_killed_with_sigkill_resumes_to_the_same_records(reference, tmp_path):
    out = tmp_path / "killed"
    p = _start_and_wait(out, 2)
    p.kill()
    p.communicate()
    assert p.returncode == -signal.SIGKILL
    assert not (out / "metrics.json").exists() and 2 <= len(read_journal(out / "trials.jsonl").records) < TRIALS
    assert main([*ARGV, "--out", str(out)]) == 0  # the same command again
    _same_records(reference, out)


def test_sigterm_stops_with_one_line_and_keeps_the_finished_trials(tmp_path):
    out = tmp_path / "stopped"
    p = _start_and_wait(out, 1)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate()
    assert p.returncode == 130, err
    kept = len(read_journal(out / "trials.jsonl").records)
    lines = [line for line in err.splitlines() if "elegant-stepping" in line]
    assert lines == [f"elegant-stepping learn: stopped after {kept} of {TRIALS} trials; "
                     f"run the same command again to resume"], err
    assert "Traceback" not in err and kept >= 1 and not (out / "metrics.json").exists()


# ---- PyBullet's save and restore ----------------------------------------------------------------------------


def test_pybullet_save_and_restore_in_memory_is_bit_exact_over_a_trial_boundary():
    """Which holds (docs/runs.md): restoring the in-memory state saved at a trial boundary and
    stepping the plant with the same torques (and the same obstacle added and removed) gives every
    joint's position and velocity bit for bit as the uninterrupted continuation did. The run's
    plant records what it is given (the physics floor's recording harness: a compiled plant's
    methods cannot be replaced on the instance)."""
    import pybullet

    from firmware_sim.plant import RigPlant
    from hil.bench.physics_floor import _RecordingLockstep

    run = learn.LearningRun(LearnConfig(trials=2, seed=SEED), harness=_RecordingLockstep)
    try:
        run.bring_up()
        run.trial(0)
        plant = run.ls.plant
        cid = plant._cid
        saved = pybullet.saveState(physicsClientId=cid)
        k0, n0 = len(plant._rec_torques), len(plant._rec_ops[-1])  # steps done, ops noted since the last
        run.trial(1)  # the whole stack: drivers, controller, learner
        torques = plant._rec_torques[k0:]
        gaps = [plant._rec_ops[k0][n0:], *plant._rec_ops[k0 + 1:]]  # gaps[k]: what came before step k of trial 1
        continuation = [[tuple(s[:2]) for s in states] for states in plant._rec_states[k0:]]
        events = [op for gap in gaps for op in gap if op[0] in ("add_obstacle", "clear_obstacles", "rewind",
                                                                 "rail_speed", "reset")]
        assert [e[0] for e in events] == ["add_obstacle", "clear_obstacles"] and len(continuation) > 1000

        pybullet.restoreState(saved, physicsClientId=cid)
        replayed = []
        for k, gap in enumerate(gaps):
            for op in gap:  # the plant's own methods, not the recording's
                if op[0] == "add_obstacle":
                    RigPlant.add_obstacle(plant, op[1])
                elif op[0] == "clear_obstacles":
                    RigPlant.clear_obstacles(plant)
            if k < len(torques):
                plant._torque = list(torques[k])
                RigPlant.step(plant)
                replayed.append([tuple(s[:2]) for s in plant._states])
        first = next((i for i, (a, b) in enumerate(zip(continuation, replayed)) if a != b), None)
        assert first is None, f"step {first}: {continuation[first]} vs {replayed[first]}"
        assert len(replayed) == len(continuation)
    finally:
        run.close()
