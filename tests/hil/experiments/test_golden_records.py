"""The house rule "a refactor proves itself by identical records", kept as a test.

``golden_*.json`` beside this file hold records written by the code before issue 17 (commit 982462a, named in each
file's ``made_by``): a 4-trial learning run of seed 3 (one mistake; the first and last trial
traced, as ``learn`` traces them for its figures) and a 5 s walk of seed 1. Every change to the
hot path (bus, drivers, controller, plant queries, compiled modules) must reproduce them field
for field (:func:`hil.analysis.records.compare`: wall-clock fields aside, NaN equal to NaN,
0.0 unlike -0.0). A deliberate change of behaviour regenerates them with the commands in
``made_by`` and says so in its commit.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil.analysis.records import compare

GOLDEN = Path(__file__).parent

pytestmark = pytest.mark.slow


def _golden(name: str) -> dict:
    return json.loads((GOLDEN / name).read_text())


def test_learn_records_identical_to_before() -> None:
    from hil.experiments.learn import FIGURE_TRACES, LearnConfig, run_learning

    golden = _golden("golden_learn_seed3_4trials.json")
    metrics = run_learning(LearnConfig(trials=4, seed=3, trace_trials=FIGURE_TRACES))
    result = compare(golden, metrics)
    assert result["same"], result["first_difference"]
    assert any(not t["success"] for t in golden["trials"])  # the record holds a mistake and its reflex


def test_walk_record_identical_to_before() -> None:
    from hil.experiments.walk import run_walk

    golden = _golden("golden_walk_seed1_5s.json")
    golden.pop("made_by")
    result = compare(golden, run_walk(5.0, seed=1))
    assert result["same"], result["first_difference"]
