"""``kill -9`` during weight saves (hil.faults.killsave): its counts carry the file stamp. The
counting itself is tested with the weights store (tests/controller/stepping/test_weights.py)."""

from __future__ import annotations

import json

from hil.faults.killsave import KILLSAVE_KIND, KILLSAVE_VERSION, kill_during_saves


def test_the_counts_are_stamped_first(tmp_path):
    r = kill_during_saves(3, tmp_path / "k", seed=0)
    assert list(r)[:3] == ["format", "format_version", "project_version"]
    assert r["format"] == KILLSAVE_KIND == "killsave" and r["format_version"] == KILLSAVE_VERSION == 1
    assert r["kills"] == 3 and r["corrupt_loads"] == 0


def test_killsave_json_is_a_stamped_file(tmp_path):
    from hil.cli import main

    out = tmp_path / "k.json"
    assert main(["killsave", "--kills", "2", "--folder", str(tmp_path / "w"), "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["format"] == "killsave" and written["format_version"] == 1 and written["project_version"]
    assert written["kills"] == 2
