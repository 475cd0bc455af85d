"""The held-out table: intervals that can be checked by hand, rows from a sweep folder."""

from __future__ import annotations

import json

import pytest

from hil.analysis import heldout


def test_wilson_interval_matches_the_formula_and_stays_in_0_1():
    lo, hi = heldout.wilson95(16, 20)
    assert lo == pytest.approx(0.5840, abs=1e-3) and hi == pytest.approx(0.9193, abs=1e-3)
    assert heldout.wilson95(20, 20)[1] == 1.0 and heldout.wilson95(0, 20)[0] == 0.0
    assert heldout.wilson95(0, 0) == (0.0, 1.0)


def test_bootstrap_median_is_seeded_and_brackets_the_median():
    values = [0, 1, 2, 3, 5, 5, 6, 7, 9, 150]
    a, b = heldout.median_ci95(values), heldout.median_ci95(values)
    assert a == b and a[0] == 5.0 and a[1] <= 5.0 <= a[2]


def _cell(root, method, seed, success, heights=None):
    folder = root / "cells" / f"{method}_s{seed}"
    folder.mkdir(parents=True)
    trials = [{"success": ok, "obstacle_height_m": (heights[i % len(heights)] if heights else 0.08),
               "contact_misses": 0 if ok else 1} for i, ok in enumerate(success)]
    (folder / "metrics.json").write_text(json.dumps({"config": {"method": method, "seed": seed}, "trials": trials}))


def test_the_table_counts_late_mistakes_per_seed_and_method(tmp_path):
    _cell(tmp_path, "improved", 1000, [False] * 3 + [True] * 147)
    _cell(tmp_path, "improved", 1001, [True] * 120 + [False] + [True] * 29)
    _cell(tmp_path, "paper", 1000, [False] * 150)
    rows = heldout.seed_rows(tmp_path)
    assert [(r["seed"], r["ttc"], r["after_50"], r["after_100"]) for r in rows["improved"]] == [
        (1000, 2, 0, 0), (1001, 0, 1, 1)]  # 9 of 10 from trial 2
    assert rows["paper"][0]["ttc"] is None and rows["paper"][0]["ttc_value"] == 150
    text = heldout.markdown(tmp_path)
    assert "| 1001 | 0, 1, 1, 0.993 | - |" in text
    assert "| improved | 2 |" in text and "1/2 [" in text and "(1 never)" in text
    assert heldout.main([str(tmp_path / "nothing")]) == 3


def test_mixed_heights_get_their_own_table(tmp_path):
    _cell(tmp_path, "improved", 1000, [True, False] * 75, heights=[0.04, 0.16])
    text = heldout.markdown(tmp_path)
    assert "0.04 m" in text and "25/25 = 1.000" in text and "0/25 = 0.000" in text
