"""Learned weights on disk: round trip, every corruption a clear WeightsError, the fallback order
file -> .prev -> zeros, the .prev copy, stale temporary files, and kill -9 during saves."""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess

import numpy as np
import pytest

from controller.errors import project_version
from controller.stepping.weights import (SCHEMA_VERSION, WeightsError, checksum, load_weights, load_weights_or_fallback,
                                         prev_path, read_weights, save_weights, stale_temporaries)
from hil.cli import main
from hil.faults.killsave import kill_during_saves
from tests.fakes import FsyncSpy, ident

W = np.linspace(-0.1, 0.1, 28)
CHECKSUM_ZEROS_2 = "4255edc5df120c7e33328bbbfec3ae9dddd983d36ebd119e94b4a9bbc345c701"  # schema 2, pinned
CHECKSUM_ZEROS_3 = "79046e54411d3a1d8f879ab1ff598620d9d66e1f9e5dcb211386848251b94949"  # schema 3, "0.1.0"


def write_npz(path, weights=W, cell_width_m=0.04, schema_version=SCHEMA_VERSION, digest=None, version="9.9.9",
              **extra):
    """A schema-3-shaped file (schema 2: without ``project_version``) written by hand, to craft what
    save_weights never writes."""
    weights = np.asarray(weights, dtype="<f8")
    digest = checksum(weights, cell_width_m, schema_version, version) if digest is None else digest
    if schema_version != 2:
        extra.setdefault("project_version", np.array(version))
    np.savez(path, weights=weights, cell_width_m=np.float64(cell_width_m), schema_version=np.int64(schema_version),
             checksum=np.array(digest), **extra)


def test_round_trip_with_schema_version_and_checksum(tmp_path):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    assert np.array_equal(load_weights(path, 28, 0.04), W)
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {"weights", "cell_width_m", "schema_version", "project_version", "checksum"}
        assert int(data["schema_version"]) == SCHEMA_VERSION == 3
        assert data["project_version"].shape == () and str(data["project_version"]) == project_version()
        assert data["checksum"].dtype.kind == "U"
        assert str(data["checksum"]) == checksum(W, 0.04, 3, project_version())
    w2 = np.arange(12.0).reshape(3, 4) * 1e-3
    save_weights(path, w2, 0.05)
    assert np.array_equal(load_weights(path, 4, 0.05, n_contexts=3), w2)
    assert not list(tmp_path.glob("*.tmp"))


def test_checksum_covers_shape_width_version_and_bytes():
    base = checksum(W, 0.04, 3, "0.1.0")
    assert checksum(W.copy(), 0.04, 3, "0.1.0") == base and len(base) == 64
    assert checksum(W.reshape(4, 7), 0.04, 3, "0.1.0") != base
    assert checksum(W, 0.0400001, 3, "0.1.0") != base
    assert checksum(W, 0.04, 2, "0.1.0") != base
    assert checksum(W, 0.04, 3, "0.1.1") != base and checksum(W, 0.04, 3, "") != base  # schema 3: the project version
    assert checksum(W, 0.04, 2, "0.1.0") == checksum(W, 0.04, 2) == checksum(W, 0.04, 2, "x")  # schema 2: none
    assert checksum(W, 0.04) == checksum(W, 0.04, SCHEMA_VERSION, "")
    w = W.copy()
    w[5] = np.nextafter(w[5], 1.0)
    assert checksum(w, 0.04, 3, "0.1.0") != base
    # the encoding itself, pinned: a file written by this version is read by the next ones
    assert checksum(np.zeros(2), 0.5, 2) == checksum(np.zeros(2), 0.5, 2, "ignored")
    assert checksum(np.zeros(2), 0.5, 2) == CHECKSUM_ZEROS_2
    assert checksum(np.zeros(2), 0.5, 3, "0.1.0") == CHECKSUM_ZEROS_3


def test_save_refuses_what_it_would_not_load(tmp_path):
    for bad in (np.full(28, np.nan), np.array([0.0, np.inf]), np.zeros((2, 2, 2)), np.zeros(0)):
        with pytest.raises(ValueError):
            save_weights(tmp_path / "w.npz", bad, 0.04)
    with pytest.raises(ValueError, match="cell_width_m"):
        save_weights(tmp_path / "w.npz", W, 0.0)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.1, 0.25, 0.5, 0.75, 0.9, 0.99])
def test_a_truncated_file_is_a_clear_error(tmp_path, fraction):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(WeightsError, match=r"w\.npz: not a readable weights file: (empty|truncated)"):
        load_weights(path, 28, 0.04)
    path.write_bytes(data[:-1])
    with pytest.raises(WeightsError, match="truncated or damaged"):
        load_weights(path, 28, 0.04)


def test_a_flipped_byte_anywhere_gives_an_error_or_the_very_weights_saved(tmp_path):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    data = path.read_bytes()
    middle = bytearray(data)
    middle[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(middle))
    with pytest.raises(WeightsError, match="w.npz: "):
        load_weights(path, 28, 0.04)
    start = data.index(W.tobytes())
    digest = checksum(W, 0.04, SCHEMA_VERSION, project_version()).encode("utf-32-le")
    guarded = set(range(start, start + W.nbytes)) | set(range(data.index(digest), data.index(digest) + 256))
    for i in range(len(data)):  # some zip header bytes (time stamps, zip64 place holders) are never read
        flipped = bytearray(data)
        flipped[i] ^= 0x5A
        path.write_bytes(bytes(flipped))
        try:
            got = load_weights(path, 28, 0.04)
        except WeightsError:
            continue
        assert i not in guarded and np.array_equal(got, W), f"byte {i}"


@pytest.mark.parametrize("make,match", [
    (lambda p: p.write_text("weights: 0.1, 0.2\n"), "not an .npz archive"),
    (lambda p: p.write_bytes(b""), "empty"),
    (lambda p: np.savez(p, weights=W), "array 'cell_width_m' missing"),
    (lambda p: np.savez(p, cell_width_m=0.04), "array 'weights' missing"),
    (lambda p: np.savez(p, weights=W, cell_width_m=0.04, schema_version=2), "array 'checksum' missing"),
    (lambda p: write_npz(p, schema_version=2, project_version=np.array("1")), r"unknown arrays \['project_version'\]"),
    (lambda p: np.savez(p, weights=W, cell_width_m=0.04, schema_version=3, checksum=checksum(W, 0.04, 3, "")),
     r"array 'project_version' missing \(schema 3 has exactly"),
    (lambda p: write_npz(p, version="1.0", digest=checksum(W, 0.04, 3, "1.1")), "checksum mismatch"),
    (lambda p: write_npz(p, project_version=np.array(3)), r"project_version is int64 of shape \(\), expected a scalar"),
    (lambda p: np.savez(p, weights=W, cell_width_m=0.04, checksum=checksum(W, 0.04)), "'schema_version' missing"),
    (lambda p: write_npz(p, extra=np.zeros(2)), r"unknown arrays \['extra'\]"),
    (lambda p: write_npz(p, schema_version=4, version="7.0"),
     r"weights schema version 4 \(written by elegant-stepping 7.0\) is not one this version of elegant-stepping "
     r"\(.*\) reads \(1, 2, 3\)"),
    (lambda p: write_npz(p, schema_version=0, project_version=np.array(0.5)),
     r"weights schema version 0 is not one this version"),  # a writer that is not text: not named
    (lambda p: write_npz(p, schema_version=1), "schema version 1 in a schema_version array: a legacy file has exactly"),
    (lambda p: write_npz(p, digest=checksum(W * 2, 0.04)), "checksum mismatch"),
    (lambda p: write_npz(p, digest="0" * 64), "checksum mismatch"),
    (lambda p: write_npz(p, weights=np.zeros(27)), r"\(27,\) weights, this controller has 28 cells"),
    (lambda p: write_npz(p, weights=np.zeros((2, 28))), r"\(2, 28\) weights, this controller has 28 cells"),
    (lambda p: write_npz(p, cell_width_m=0.05), "cell width 0.05 m, this controller uses 0.04 m"),
    (lambda p: write_npz(p, weights=np.full(28, np.nan)), "NaN or infinity"),
    (lambda p: write_npz(p, weights=np.r_[np.zeros(27), np.inf]), "NaN or infinity"),
    (lambda p: np.savez(p, weights=W.astype(np.float32), cell_width_m=0.04, schema_version=2,
                        checksum=checksum(W, 0.04, 2)), "weights are float32, schema 2 stores float64"),
    (lambda p: np.savez(p, weights=W.astype(np.float32), cell_width_m=0.04, schema_version=3,
                        project_version=np.array("1"), checksum=checksum(W, 0.04, 3, "1")),
     "weights are float32, schema 3 stores float64"),
    (lambda p: np.savez(p, weights=np.array([object()] * 28), cell_width_m=0.04), "not a readable"),
])
def test_each_corruption_is_a_clear_error_naming_the_file(tmp_path, make, match):
    path = tmp_path / "w.npz"
    make(path)
    with pytest.raises(WeightsError, match=match) as exc:
        load_weights(path, 28, 0.04)
    assert str(exc.value).startswith(str(path))


def test_a_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(WeightsError, match=r"w\.npz: no such weights file"):
        load_weights(tmp_path / "w.npz", 28, 0.04)


def test_legacy_files_load_with_a_warning_and_the_next_save_upgrades_them(tmp_path, caplog):
    path = tmp_path / "w.npz"
    np.savez(path, weights=W, cell_width_m=np.float64(0.04))  # what save_weights wrote before schema 2
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        assert np.array_equal(load_weights(path, 28, 0.04), W)
    assert "legacy weights file" in caplog.text
    save_weights(path, W * 2, 0.04)
    with np.load(path, allow_pickle=False) as data:
        assert int(data["schema_version"]) == SCHEMA_VERSION
    assert np.array_equal(load_weights(prev_path(path), 28, 0.04), W)  # the legacy file kept as .prev


def test_save_keeps_the_previous_good_file_as_prev(tmp_path, caplog):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    assert not prev_path(path).exists()
    save_weights(path, W * 2, 0.04)
    assert np.array_equal(load_weights(path, 28, 0.04), W * 2)
    assert np.array_equal(load_weights(prev_path(path), 28, 0.04), W)
    save_weights(path, W * 3, 0.04)
    assert np.array_equal(load_weights(prev_path(path), 28, 0.04), W * 2)
    path.write_bytes(b"PK\x03\x04 garbage")  # a damaged file is never kept as the good copy
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        save_weights(path, W * 4, 0.04)
    assert "is left as it is" in caplog.text
    assert np.array_equal(load_weights(path, 28, 0.04), W * 4)
    assert np.array_equal(load_weights(prev_path(path), 28, 0.04), W * 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz", "w.npz.prev"]


def test_fallback_order_file_then_prev_then_zeros(tmp_path, caplog):
    path = tmp_path / "w.npz"
    caplog.set_level(logging.INFO, logger="controller.stepping.weights")
    w, source = load_weights_or_fallback(path, 28, 0.04)
    assert source == "zeros" and np.array_equal(w, np.zeros(28))
    assert [r.levelname for r in caplog.records] == ["INFO", "INFO", "WARNING"]  # two missing files, then zeros
    assert "starting from zeros" in caplog.records[-1].getMessage()

    save_weights(path, W, 0.04)
    save_weights(path, W * 2, 0.04)
    caplog.clear()
    w, source = load_weights_or_fallback(path, 28, 0.04)
    assert source == "file" and np.array_equal(w, W * 2) and not caplog.records

    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    w, source = load_weights_or_fallback(path, 28, 0.04)
    assert source == "prev" and np.array_equal(w, W)
    errors = [r for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and "w.npz: not a readable weights file: truncated" in errors[0].getMessage()
    assert "previous good copy" in caplog.text

    prev_path(path).write_bytes(b"\x00" * 100)
    caplog.clear()
    w, source = load_weights_or_fallback(path, 28, 0.04)
    assert source == "zeros" and np.array_equal(w, np.zeros(28))
    assert [r.levelname for r in caplog.records] == ["ERROR", "ERROR", "WARNING"]


def test_fallback_for_another_controller_shape_is_zeros_of_its_shape(tmp_path, caplog):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    save_weights(path, W, 0.04)
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        w, source = load_weights_or_fallback(path, 28, 0.04, n_contexts=4)
    assert source == "zeros" and w.shape == (4, 28) and not w.any()
    assert "4 contexts x 28 cells" in caplog.text
    w, source = load_weights_or_fallback(path, 28, 0.02)
    assert source == "zeros" and w.shape == (28,)


def test_stale_temporaries_of_dead_processes_are_removed_by_the_next_save(tmp_path):
    path = tmp_path / "w.npz"
    dead = subprocess.Popen(["true"])
    dead.wait()
    # a live process of our own (not our parent: a broken liveness check must never signal a
    # process that matters, such as the shell or test runner that started us)
    live = subprocess.Popen(["sleep", "60"])
    try:
        stale = tmp_path / f"w.npz.{dead.pid}.abcdefgh.tmp"
        mine = tmp_path / f"w.npz.{os.getpid()}.abcdefgh.tmp"
        alive = tmp_path / f"w.npz.{live.pid}.abcdefgh.link.tmp"
        for p in (stale, mine, alive):
            p.write_bytes(b"PK\x03\x04 half a file")
        assert stale_temporaries(path) == [stale]
        save_weights(path, W, 0.04)
        assert not stale.exists() and mine.exists() and alive.exists()
        assert np.array_equal(read_weights(path)[0], W)  # loading never writes: the others stay
        assert mine.exists() and alive.exists() and live.poll() is None
    finally:
        live.kill()
        live.wait()


def test_kill_9_during_saves_never_gives_a_corrupt_load(tmp_path):
    r = kill_during_saves(50, tmp_path / "k", seed=1)
    assert r["kills"] == 50 and r["corrupt_loads"] == 0 and r["prev_corrupt"] == 0 and r["child_errors"] == 0
    assert r["loads_ok_from_file"] + r["loads_from_prev"] + r["zeros"] == 50
    assert r["zeros"] == r["strict_load_errors_before_first_save"]  # zeros only before the first complete save
    assert r["kills_mid_save"] >= 10  # the kills do land inside saves
    assert r["saves_completed"] > 0 and r["tmp_files_left"] <= 2 and r["elapsed_s"] > 0
    # kills within the first save or two: zeros until a save completes, never garbage
    early = kill_during_saves(20, tmp_path / "early", seed=2, max_delay_s=0.003)
    assert early["corrupt_loads"] == 0 and early["prev_corrupt"] == 0
    assert early["zeros"] == early["strict_load_errors_before_first_save"]
    assert early["loads_ok_from_file"] + early["loads_from_prev"] + early["zeros"] == 20


def test_killsave_command_writes_the_counts(tmp_path, capsys):
    out = tmp_path / "killsave.json"
    assert main(["killsave", "--kills", "5", "--seed", "3", "--folder", str(tmp_path / "k"), "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["kills"] == 5 and r["corrupt_loads"] == 0 and r["seed"] == 3
    assert "5 kill -9s" in capsys.readouterr().err
    try:  # a usage error: exit 2, whether main returns it or argparse exits with it
        code = main(["killsave", "--kills", "0"])
    except SystemExit as exc:
        code = exc.code
    assert code == 2 and "--kills" in capsys.readouterr().err


def test_generations_rotate_on_each_save_and_the_fallback_tries_them_in_order(tmp_path, caplog):
    from controller.stepping.weights import generation_path

    path = tmp_path / "w.npz"
    for k in range(1, 6):
        save_weights(path, W * k, 0.04, generations=3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz", "w.npz.prev", "w.npz.prev2"]
    assert [load_weights(generation_path(path, g), 28, 0.04)[0] / W[0] for g in range(3)] == pytest.approx([5, 4, 3])
    # a damaged middle generation is dropped by the next rotation, never shifted down as if good
    generation_path(path, 1).write_bytes(b"PK\x03\x04 damaged")
    save_weights(path, W * 6, 0.04, generations=3)
    assert [load_weights(generation_path(path, g), 28, 0.04)[0] / W[0] for g in range(3)] == pytest.approx([6, 5, 3])
    # the fallback: file, prev, prev2 in order
    path.write_bytes(b"garbage")
    generation_path(path, 1).write_bytes(b"garbage")
    w, source = load_weights_or_fallback(path, 28, 0.04, generations=3)
    assert source == "prev2" and np.array_equal(w, W * 3)
    w, source = load_weights_or_fallback(path, 28, 0.04)  # two generations by default: file, prev
    assert source == "zeros"
    with pytest.raises(ValueError, match="generations"):
        save_weights(path, W, 0.04, generations=0)


def test_resume_sets_incompatible_generations_aside_and_loads_the_first_that_fits(tmp_path):
    from controller.stepping.weights import IncompatibleWeights, WeightsError, resume_weights

    assert issubclass(IncompatibleWeights, WeightsError)
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04, generations=3)          # -> .prev2: fits
    save_weights(path, W[:20], 0.04, generations=3)     # -> .prev: 20 cells
    save_weights(path, W, 0.05, generations=3)          # the file: another cell width
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    r = resume_weights(path, 28, 0.04, generations=3, set_aside_incompatible=True)
    assert r.source == "prev2" and np.array_equal(r.weights, W)
    assert [a[0] for a in r.set_aside] == [str(path), str(path) + ".prev"]
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names[0] == "w.npz.incompatible-" + names[0].split("incompatible-")[1] and "w.npz.prev2" in names
    for old, moved, _ in r.set_aside:
        assert open(moved, "rb").read() == before[os.path.basename(old)]  # byte for byte
    # the same second twice: never over another set-aside file
    save_weights(path, W, 0.05)
    r2 = resume_weights(path, 28, 0.04, generations=3)
    assert len(r2.set_aside) == 1 and r2.set_aside[0][1] != r.set_aside[0][1] and len(list(tmp_path.glob("*incompat*"))) == 3


# --------------------------------------------------------------------------- schema 3: the project's version
def test_schema_2_and_3_files_load_and_say_which_they_are(tmp_path, caplog):
    from controller.stepping.weights import READ_VERSIONS, read_stored_weights

    assert READ_VERSIONS == (1, 2, 3)
    v2, v3 = tmp_path / "v2.npz", tmp_path / "v3.npz"
    write_npz(v2, schema_version=2)  # what the previous version wrote
    write_npz(v3, version="0.0.7")
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        a, b = read_stored_weights(v2), read_stored_weights(v3)
    assert caplog.text == ""  # neither is legacy
    assert (a.schema_version, a.project_version, a.cell_width_m) == (2, None, 0.04) and np.array_equal(a.weights, W)
    assert (b.schema_version, b.project_version) == (3, "0.0.7") and np.array_equal(b.weights, W)
    assert np.array_equal(load_weights(v2, 28, 0.04), W) and np.array_equal(load_weights(v3, 28, 0.04), W)
    save_weights(v2, W * 2, 0.04)  # the next save writes schema 3 and keeps the schema-2 file as .prev
    assert read_stored_weights(v2).schema_version == 3 and read_stored_weights(v2).project_version == project_version()
    assert read_stored_weights(prev_path(v2)).schema_version == 2
    np.savez(tmp_path / "v1.npz", weights=W, cell_width_m=np.float64(0.04))
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        legacy = read_stored_weights(tmp_path / "v1.npz")
    assert (legacy.schema_version, legacy.project_version) == (1, None) and "legacy weights file" in caplog.text


def test_the_file_holds_no_pickle_and_loads_with_allow_pickle_false(tmp_path):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    with np.load(path, allow_pickle=False) as data:  # would raise on an object array
        kinds = {name: data[name].dtype.kind for name in data.files}
    assert kinds == {"weights": "f", "cell_width_m": "f", "schema_version": "i", "project_version": "U",
                     "checksum": "U"}


def test_an_unknown_version_is_refused_naming_file_and_version_and_is_never_written_over(tmp_path, caplog):
    from controller.stepping.weights import IncompatibleWeights, UnknownWeightsVersion, resume_weights

    path = tmp_path / "w.npz"
    write_npz(path, schema_version=7, version="2.0.0")
    newer = path.read_bytes()
    with pytest.raises(UnknownWeightsVersion, match=r"w\.npz: weights schema version 7 \(written by elegant-stepping "
                                                    r"2\.0\.0\)") as exc:
        read_weights(path)
    assert isinstance(exc.value, IncompatibleWeights)
    # a save keeps it as .prev (as it keeps any good copy), never drops it
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        save_weights(path, W * 2, 0.04)
    assert prev_path(path).read_bytes() == newer and "kept as" in caplog.text
    save_weights(path, W * 3, 0.04, generations=3)  # and rotates it down like a good copy
    from controller.stepping.weights import generation_path
    assert generation_path(path, 2).read_bytes() == newer
    # the daemon's loader sets it aside rather than leave it where a save could drop it
    r = resume_weights(path, 28, 0.04, generations=3)
    assert r.source == "file" and np.allclose(r.weights, W * 3)
    assert len(r.set_aside) == 1 and open(r.set_aside[0][1], "rb").read() == newer
    assert "schema version 7" in r.set_aside[0][2]


# --------------------------------------------------------------------------- fsync, observed
@pytest.mark.parametrize("existing", [False, True], ids=["first save", "replacing"])
def test_save_fsyncs_the_new_file_before_the_rename_and_the_folder_after_it(tmp_path, monkeypatch, existing):
    path = tmp_path / "w.npz"
    if existing:
        save_weights(path, W, 0.04)
    old_ino = os.stat(path).st_ino if existing else None
    spy = FsyncSpy(monkeypatch, path)
    save_weights(path, W * 2, 0.04)
    file_calls = [c for c in spy.calls if c["id"] == ident(path)]
    dir_calls = [c for c in spy.calls if c["id"] == ident(tmp_path)]
    assert len(file_calls) == 1 and not file_calls[0]["dir"], spy.calls  # the very file now at the path
    assert file_calls[0]["at_path"] == old_ino  # ... while the old one was still there
    assert len(dir_calls) >= 1 and all(c["dir"] for c in dir_calls), spy.calls
    assert dir_calls[-1]["at_path"] == os.stat(path).st_ino  # the folder, after the rename
    assert spy.calls.index(file_calls[0]) < spy.calls.index(dir_calls[-1])
    assert np.array_equal(load_weights(path, 28, 0.04), W * 2)


def test_a_prev_copied_where_hard_links_fail_is_fsynced_before_it_is_renamed(tmp_path, monkeypatch):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    old = path.read_bytes()

    def no_link(src, dst):
        raise OSError(1, "hard links not supported")

    monkeypatch.setattr(os, "link", no_link)
    spy = FsyncSpy(monkeypatch, prev_path(path))
    save_weights(path, W * 2, 0.04)
    assert prev_path(path).read_bytes() == old
    prev_calls = [c for c in spy.calls if c["id"] == ident(prev_path(path))]
    assert len(prev_calls) == 1 and prev_calls[0]["at_path"] is None  # fsynced before it became .prev
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz", "w.npz.prev"]


# --------------------------------------------------------------------------- the rest, found by mutation testing
def test_generation_paths_and_a_negative_generation():
    from controller.stepping.weights import generation_name, generation_path

    p = "/x/w.npz"
    assert [generation_path(p, k).name for k in range(4)] == ["w.npz", "w.npz.prev", "w.npz.prev2", "w.npz.prev3"]
    assert [generation_name(k) for k in range(4)] == ["file", "prev", "prev2", "prev3"]
    with pytest.raises(ValueError, match="^generation -1 < 0$"):
        generation_path(p, -1)


def test_set_aside_names_the_copy_by_its_utc_time_and_never_over_another(tmp_path):
    from controller.stepping.weights import set_aside

    now = 1767225600.0 + 3723.9  # 2026-01-01 01:02:03.9 UTC
    moved = []
    for _ in range(3):
        (tmp_path / "w.npz").write_bytes(b"x")
        moved.append(set_aside(tmp_path / "w.npz", now=now).name)
    assert moved == ["w.npz.incompatible-20260101T010203Z", "w.npz.incompatible-20260101T010203Z-1",
                     "w.npz.incompatible-20260101T010203Z-2"]
    assert not (tmp_path / "w.npz").exists()


def test_the_checksum_is_of_the_float64_values_whatever_the_input_type():
    assert checksum(np.arange(3), 0.5, 3, "v") == checksum(np.arange(3.0), 0.5, 3, "v")
    assert checksum(np.arange(3, dtype=np.float32), 0.5, 2) == checksum(np.arange(3.0), 0.5, 2)
    assert checksum(np.arange(6.0).reshape(2, 3).T, 0.5, 2) == checksum(np.array([[0.0, 3], [1, 4], [2, 5]]), 0.5, 2)


def test_a_live_process_s_temporary_is_never_stale_and_checking_does_not_signal_it(tmp_path, monkeypatch):
    import subprocess
    import sys

    path = tmp_path / "w.npz"
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        tmp = tmp_path / f"w.npz.{child.pid}.abc.tmp"
        tmp.write_bytes(b"x")
        assert stale_temporaries(path) == []
        assert child.poll() is None  # still running: only asked (signal 0), never signalled
    finally:
        child.kill()
        child.wait()
    assert stale_temporaries(path) == [tmp]

    def not_ours(pid, sig):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "kill", not_ours)  # someone else's live process
    assert stale_temporaries(path) == []


def test_a_failed_copy_of_prev_leaves_nothing_behind_and_raises_its_own_error(tmp_path, monkeypatch):
    import shutil

    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    old = path.read_bytes()

    def no_link(src, dst):
        raise OSError(1, "hard links not supported")

    def full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "link", no_link)
    monkeypatch.setattr(shutil, "copyfile", full)
    with pytest.raises(OSError, match="No space left"):
        save_weights(path, W * 2, 0.04)
    assert path.read_bytes() == old and sorted(p.name for p in tmp_path.iterdir()) == ["w.npz"]


def test_keeping_prev_is_skipped_with_a_warning_naming_both_files(tmp_path, caplog):
    path = tmp_path / "w.npz"
    path.write_bytes(b"PK\x03\x04 damaged")
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        save_weights(path, W, 0.04)
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and msgs[0].startswith(
        f"{path} is not a valid weights file, so {prev_path(path)} is left as it is ({path}: not a readable")


def test_four_generations_rotate_each_one_place_down(tmp_path):
    from controller.stepping.weights import generation_path

    path = tmp_path / "w.npz"
    for k in range(1, 7):
        save_weights(path, W * k, 0.04, generations=4)
    assert [load_weights(generation_path(path, g), 28, 0.04)[0] / W[0] for g in range(4)] == pytest.approx([6, 5, 4, 3])
    assert len(list(tmp_path.iterdir())) == 4


@pytest.mark.parametrize("name", ["cell_width_m", "schema_version", "checksum", "project_version"])
def test_a_scalar_stored_as_an_array_is_refused_naming_it(tmp_path, name):
    path = tmp_path / "w.npz"
    arrays = {"weights": W, "cell_width_m": np.float64(0.04), "schema_version": np.int64(3),
              "project_version": np.array("1"), "checksum": np.array(checksum(W, 0.04, 3, "1"))}
    arrays[name] = np.array([arrays[name]])  # shape (1,)
    np.savez(path, **arrays)
    with pytest.raises(WeightsError, match=rf"w\.npz: {name} is \S+ of shape \(1,\), expected a scalar"):
        read_weights(path)


def test_the_fallback_never_writes_even_over_another_configuration_s_file(tmp_path):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.05)  # another cell width
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    w, source = load_weights_or_fallback(path, 28, 0.04)
    assert source == "zeros" and {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_an_unknown_version_kept_as_prev_is_logged_naming_both(tmp_path, caplog):
    path = tmp_path / "w.npz"
    write_npz(path, schema_version=9, version="3.0")
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        save_weights(path, W, 0.04)
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and msgs[0].startswith(f"{path}: weights schema version 9 (written by elegant-stepping 3.0)")
    assert msgs[0].endswith(f"; kept as {prev_path(path)}")


def test_one_generation_keeps_no_prev_and_integers_and_lists_are_saved_as_float64(tmp_path):
    path = tmp_path / "deep" / "er" / "w.npz"  # folders made as needed
    save_weights(path, [1, 2, 3], 0.04, generations=1)
    save_weights(path, [4, 5, 6], 0.04, generations=1)
    assert sorted(p.name for p in path.parent.iterdir()) == ["w.npz"]
    got = load_weights(path, 3, 0.04)
    assert got.dtype == np.float64 and np.array_equal(got, [4.0, 5.0, 6.0])


def test_refusals_to_save_say_why(tmp_path):
    with pytest.raises(ValueError, match=r"^weights must be a non-empty 1-D or 2-D array, got shape \(2, 2, 2\)$"):
        save_weights(tmp_path / "w.npz", np.zeros((2, 2, 2)), 0.04)
    with pytest.raises(ValueError, match="^weights contain NaN or infinity: not saved$"):
        save_weights(tmp_path / "w.npz", [0.0, np.inf], 0.04)
    with pytest.raises(ValueError, match=r"^cell_width_m must be positive, got nan$"):
        save_weights(tmp_path / "w.npz", W, np.nan)
    with pytest.raises(ValueError, match="^generations must be at least 1, got 0$"):
        save_weights(tmp_path / "w.npz", W, 0.04, generations=0)


def test_the_temporary_file_is_named_for_the_stale_file_sweep_in_the_same_folder(tmp_path, monkeypatch):
    import re

    path = tmp_path / "w.npz"
    seen = []
    real = os.fsync

    def spy(fd):
        seen.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    save_weights(path, W, 0.04)
    files = [p for p in seen if not os.path.isdir(p)]
    assert len(files) == 1, seen
    assert re.fullmatch(rf"{re.escape(str(tmp_path))}/w\.npz\.{os.getpid()}\.[^/]+\.tmp", files[0]), files[0]


def test_resume_tries_three_generations_by_default_and_never_fewer_than_one(tmp_path):
    from controller.stepping.weights import generation_path, resume_weights

    path = tmp_path / "w.npz"
    save_weights(generation_path(path, 3), W, 0.04, generations=1)  # only a fourth generation is good
    assert resume_weights(path, 28, 0.04).source == "zeros"
    assert resume_weights(path, 28, 0.04, generations=4).source == "prev3"
    save_weights(generation_path(path, 1), W, 0.04, generations=1)
    assert resume_weights(path, 28, 0.04, generations=1).source == "zeros"  # the file only
    assert resume_weights(path, 28, 0.04, generations=0).source == "zeros"  # at least the file
    save_weights(path, W * 2, 0.04, generations=1)
    r = resume_weights(path, 28, 0.04, generations=0)
    assert r.source == "file" and np.array_equal(r.weights, W * 2)


def test_resume_reports_why_each_earlier_generation_was_not_used_and_logs_each(tmp_path, caplog):
    from controller.stepping.weights import generation_path, resume_weights

    path = tmp_path / "w.npz"
    save_weights(generation_path(path, 1), W, 0.04, generations=1)  # prev: good
    save_weights(generation_path(path, 2), W, 0.05, generations=1)  # prev2: another configuration's
    path.write_bytes(b"PK\x03\x04 damaged")  # the file: damaged
    with caplog.at_level(logging.INFO, logger="controller.stepping.weights"):
        r = resume_weights(path, 28, 0.04, generations=4)
    assert r.source == "prev" and len(r.reasons) == 1 and r.reasons[0].startswith(f"{path}: not a readable")
    moved = r.set_aside[0][1]
    msgs = [(rec.levelname, rec.getMessage()) for rec in caplog.records]
    assert msgs == [
        ("ERROR", f"weights: {r.reasons[0]}"),
        ("WARNING", f"weights: loaded the previous good copy {generation_path(path, 1)}"),
        ("ERROR", f"weights: {r.set_aside[0][2]}: another configuration's weights, kept aside as {moved}"),
        ("INFO", f"weights: {generation_path(path, 3)}: no such weights file"),
    ]


def test_starting_from_zeros_is_warned_with_every_reason(tmp_path, caplog):
    from controller.stepping.weights import resume_weights

    path = tmp_path / "w.npz"
    path.write_bytes(b"junk")
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        r = resume_weights(path, 28, 0.04, generations=2)
    assert r.source == "zeros" and r.reasons == [f"{path}: not a readable weights file: not an .npz archive",
                                                 f"{prev_path(path)}: no such weights file"]
    assert caplog.records[-1].getMessage() == f"weights: starting from zeros (28,) ({'; '.join(r.reasons)})"


def test_an_incompatible_file_that_cannot_be_set_aside_stops_the_resume(tmp_path, monkeypatch, caplog):
    from controller.stepping.weights import resume_weights

    path = tmp_path / "w.npz"
    save_weights(path, W, 0.05)

    def no_rename(src, dst):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(os, "rename", no_rename)
    with caplog.at_level(logging.ERROR, logger="controller.stepping.weights"):
        with pytest.raises(WeightsError) as exc:
            resume_weights(path, 28, 0.04)
    assert str(exc.value) == (f"{path}: cell width 0.05 m, this controller uses 0.04 m; it could not be renamed aside "
                              "([Errno 30] Read-only file system), so the daemon will not run where it could write "
                              "over it")
    assert [r.getMessage() for r in caplog.records] == [
        f"weights: {path}: cell width 0.05 m, this controller uses 0.04 m; and it could not be renamed aside "
        "([Errno 30] Read-only file system)"]


def test_a_file_that_cannot_be_opened_is_a_weights_error_saying_so(tmp_path, monkeypatch):
    import builtins

    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    real_open = builtins.open

    def guarded(file, *a, **kw):
        if str(file) == str(path):
            raise PermissionError(13, "Permission denied")
        return real_open(file, *a, **kw)

    monkeypatch.setattr(builtins, "open", guarded)
    with pytest.raises(WeightsError, match=r"w\.npz: cannot be read \(\[Errno 13\] Permission denied\)$"):
        read_weights(path)


def test_an_unreadable_array_names_the_exception(tmp_path):
    path = tmp_path / "w.npz"
    np.savez(path, weights=np.array([object()] * 28), cell_width_m=0.04)  # pickled: never loaded
    with pytest.raises(WeightsError, match=r"w\.npz: not a readable weights file \(ValueError: "):
        read_weights(path)


def test_an_empty_project_version_is_still_checked_and_loaded(tmp_path):
    from controller.stepping.weights import read_stored_weights

    path = tmp_path / "w.npz"
    write_npz(path, version="")
    assert read_stored_weights(path).project_version == "" and np.array_equal(read_weights(path)[0], W)


def test_legacy_files_are_numbers_made_float64_with_a_warning_naming_the_file(tmp_path, caplog):
    path = tmp_path / "w.npz"
    np.savez(path, weights=np.arange(5), cell_width_m=np.float64(0.04))  # integers, legacy
    with caplog.at_level(logging.WARNING, logger="controller.stepping.weights"):
        got, width = read_weights(path)
    assert got.dtype == np.float64 and np.array_equal(got, np.arange(5.0)) and width == 0.04
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: legacy weights file (schema 1, no version or checksum); loading it, the next save rewrites it in "
        "schema 3"]
    np.savez(path, weights=np.array(["a", "b"]), cell_width_m=np.float64(0.04))
    with pytest.raises(WeightsError, match=r"w\.npz: weights are <U1, expected numbers$"):
        read_weights(path)


@pytest.mark.parametrize("weights,ok", [(np.zeros((2, 2, 2)), False), (np.zeros(0), False), (np.zeros((2, 0)), False),
                                        (np.ones(1), True), (np.ones((1, 1)), True)])
def test_the_shape_read_must_be_a_non_empty_1d_or_2d_array(tmp_path, weights, ok):
    path = tmp_path / "w.npz"
    write_npz(path, weights=weights)
    if ok:
        assert np.array_equal(read_weights(path)[0], weights)
    else:
        with pytest.raises(WeightsError, match=rf"w\.npz: weights of shape {re.escape(str(weights.shape))}, expected "
                                               r"a non-empty 1-D or 2-D array$"):
            read_weights(path)


@pytest.mark.parametrize("width", [0.0, -0.04, np.inf, np.nan])
def test_the_cell_width_read_must_be_positive_and_finite(tmp_path, width):
    path = tmp_path / "w.npz"
    write_npz(path, cell_width_m=width)
    with pytest.raises(WeightsError, match=rf"w\.npz: cell width {width} m is not positive$"):
        read_weights(path)


def test_the_fallback_logs_and_reports_another_configuration_s_file_without_moving_it(tmp_path, caplog):
    from controller.stepping.weights import resume_weights

    path = tmp_path / "w.npz"
    save_weights(path, W, 0.05)
    with caplog.at_level(logging.ERROR, logger="controller.stepping.weights"):
        r = resume_weights(path, 28, 0.04, generations=1, set_aside_incompatible=False)
    reason = f"{path}: cell width 0.05 m, this controller uses 0.04 m"
    assert r.source == "zeros" and r.reasons == [reason] and r.set_aside == [] and path.exists()
    assert [x.getMessage() for x in caplog.records] == [f"weights: {reason}"]
