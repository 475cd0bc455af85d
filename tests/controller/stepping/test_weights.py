"""Learned weights on disk: round trip, every corruption a clear WeightsError, the fallback order
file -> .prev -> zeros, the .prev copy, stale temporary files, and kill -9 during saves."""

from __future__ import annotations

import json
import logging
import os
import subprocess

import numpy as np
import pytest

from controller.stepping.weights import (SCHEMA_VERSION, WeightsError, checksum, load_weights, load_weights_or_fallback,
                                prev_path, read_weights, save_weights, stale_temporaries)
from hil.cli import main
from hil.faults.killsave import kill_during_saves

W = np.linspace(-0.1, 0.1, 28)


def write_npz(path, weights=W, cell_width_m=0.04, schema_version=SCHEMA_VERSION, digest=None, **extra):
    """A schema-2-shaped file written by hand, to craft what save_weights never writes."""
    weights = np.asarray(weights, dtype="<f8")
    digest = checksum(weights, cell_width_m, schema_version) if digest is None else digest
    np.savez(path, weights=weights, cell_width_m=np.float64(cell_width_m), schema_version=np.int64(schema_version),
             checksum=np.array(digest), **extra)


def test_round_trip_with_schema_version_and_checksum(tmp_path):
    path = tmp_path / "w.npz"
    save_weights(path, W, 0.04)
    assert np.array_equal(load_weights(path, 28, 0.04), W)
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {"weights", "cell_width_m", "schema_version", "checksum"}
        assert int(data["schema_version"]) == SCHEMA_VERSION == 2
        assert data["checksum"].dtype.kind == "U" and str(data["checksum"]) == checksum(W, 0.04)
    w2 = np.arange(12.0).reshape(3, 4) * 1e-3
    save_weights(path, w2, 0.05)
    assert np.array_equal(load_weights(path, 4, 0.05, n_contexts=3), w2)
    assert not list(tmp_path.glob("*.tmp"))


def test_checksum_covers_shape_width_version_and_bytes():
    base = checksum(W, 0.04)
    assert checksum(W.copy(), 0.04) == base and len(base) == 64
    assert checksum(W.reshape(4, 7), 0.04) != base
    assert checksum(W, 0.0400001) != base
    assert checksum(W, 0.04, schema_version=3) != base
    w = W.copy()
    w[5] = np.nextafter(w[5], 1.0)
    assert checksum(w, 0.04) != base


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
    guarded = set(range(start, start + W.nbytes)) | set(range(data.index(checksum(W, 0.04).encode("utf-32-le")),
                                                              data.index(checksum(W, 0.04).encode("utf-32-le")) + 256))
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
    (lambda p: np.savez(p, weights=W, cell_width_m=0.04, checksum=checksum(W, 0.04)), "'schema_version' missing"),
    (lambda p: write_npz(p, extra=np.zeros(2)), r"unknown arrays \['extra'\]"),
    (lambda p: write_npz(p, schema_version=3), "schema version 3, this controller reads version 2"),
    (lambda p: write_npz(p, schema_version=1), "schema version 1"),
    (lambda p: write_npz(p, digest=checksum(W * 2, 0.04)), "checksum mismatch"),
    (lambda p: write_npz(p, digest="0" * 64), "checksum mismatch"),
    (lambda p: write_npz(p, weights=np.zeros(27)), r"\(27,\) weights, this controller has 28 cells"),
    (lambda p: write_npz(p, weights=np.zeros((2, 28))), r"\(2, 28\) weights, this controller has 28 cells"),
    (lambda p: write_npz(p, cell_width_m=0.05), "cell width 0.05 m, this controller uses 0.04 m"),
    (lambda p: write_npz(p, weights=np.full(28, np.nan)), "NaN or infinity"),
    (lambda p: write_npz(p, weights=np.r_[np.zeros(27), np.inf]), "NaN or infinity"),
    (lambda p: np.savez(p, weights=W.astype(np.float32), cell_width_m=0.04, schema_version=2,
                        checksum=checksum(W, 0.04)), "float32"),
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
        assert int(data["schema_version"]) == 2
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
    stale = tmp_path / f"w.npz.{dead.pid}.abcdefgh.tmp"
    mine = tmp_path / f"w.npz.{os.getpid()}.abcdefgh.tmp"
    alive = tmp_path / f"w.npz.{os.getppid()}.abcdefgh.link.tmp"
    for p in (stale, mine, alive):
        p.write_bytes(b"PK\x03\x04 half a file")
    assert stale_temporaries(path) == [stale]
    save_weights(path, W, 0.04)
    assert not stale.exists() and mine.exists() and alive.exists()
    assert np.array_equal(read_weights(path)[0], W)  # loading never writes: the others stay
    assert mine.exists() and alive.exists()


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
    assert main(["killsave", "--kills", "0"]) == 2


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
