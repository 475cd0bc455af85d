"""The physics floor of a learning run (hil.bench.physics_floor) and its figures in ``bench``
(hil.bench.run). The replay is checked bit for bit; the timings only for their structure (no
wall-clock figure is asserted: these machines are shared)."""

from __future__ import annotations

import statistics
from dataclasses import replace

import pytest

from hil.bench import physics_floor as pf

SECONDS = 3.0  # bring-up and its second of walking take about 2.1 s: then part of a trial, with its obstacle


@pytest.fixture(scope="module")
def rec() -> pf.Recording:
    return pf.record(SECONDS, seed=0)


def test_the_recording_holds_every_step_and_the_stack_queries_at_their_rates(rec):
    assert rec.steps == len(rec.states) == len(rec.ops) - 1
    assert rec.sim_s == pytest.approx(SECONDS) and rec.steps == round(SECONDS * rec.rig.physics_hz)
    counts = rec.counts()
    assert counts["add_obstacle"] == rec.trials == 1  # the run ends inside the first trial
    assert counts["contacts"] == rec.steps  # the sensor board reads the switches every step, once
    # the range ray and the profile beams at the sensor's 50 Hz
    assert counts["range"] == counts["profile"] == pytest.approx(rec.sim_s * 50, abs=2)
    assert counts["rail"] > 0 and counts.get("foot", 0) > 0
    assert any(any(t != 0.0 for t in step) for step in rec.torques_nm)


def test_both_replays_reproduce_the_recorded_joint_states_bit_for_bit(rec):
    for queries in (False, True):
        replayed = pf.replay(rec, queries=queries)
        assert replayed["steps"] == rec.steps
        assert pf.first_difference(rec.states, replayed["states"]) is None
        assert pf.exact(rec, replayed)


def test_a_replay_of_other_torques_is_caught_at_the_step_it_differs(rec):
    k = rec.steps // 2
    torques = list(rec.torques_nm)
    hip, knee = torques[k]
    torques[k] = (hip + 1e-9, knee)
    other = replace(rec, torques_nm=tuple(torques))
    replayed = pf.replay(other)
    assert not pf.exact(rec, replayed)
    assert pf.first_difference(rec.states, replayed["states"]) == k


def test_the_unrecorded_stack_run_is_the_recorded_motion(rec):
    stack = pf.time_stack(SECONDS, seed=0)
    assert stack["steps"] == rec.steps
    assert pf.first_difference([rec.states[-1]], [stack["last_state"]]) is None
    assert stack["cpu_s"] > 0 and stack["wall_s"] > 0


def test_measure_reports_medians_of_interleaved_pairs():
    m = pf.measure(SECONDS, seed=0, pairs=3)
    pairs = m["detail"]["pairs"]
    assert len(pairs) == 3 and m["detail"]["replay_exact"] is True
    for key in ("floor_us_per_step", "floor_queries_us_per_step", "stack_us_per_step"):
        assert m[key] > 0
        assert m[key] == statistics.median(p[key] for p in pairs)
    for p in pairs:
        assert p["stack_vs_floor"] == pytest.approx(p["stack_us_per_step"] / p["floor_us_per_step"], rel=1e-12)
        assert p["stack_vs_floor_queries"] == pytest.approx(p["stack_us_per_step"] / p["floor_queries_us_per_step"],
                                                            rel=1e-12)
    assert m["stack_vs_floor"] == statistics.median(p["stack_vs_floor"] for p in pairs)
    assert m["stack_vs_floor_queries"] == statistics.median(p["stack_vs_floor_queries"] for p in pairs)
    assert m["stack_vs_floor"] > 0 and m["stack_vs_floor_queries"] > 0


def test_fewer_than_three_pairs_is_refused():
    with pytest.raises(ValueError, match="pairs"):
        pf.measure(SECONDS, pairs=2)


def test_bench_reports_the_floor_and_no_figure_of_another_motion(monkeypatch):
    import hil.bench.run as bench

    seen = {}

    def floor(seconds, seed=0, pairs=pf.DEFAULT_PAIRS):
        seen.update(seconds=seconds, seed=seed, pairs=pairs)
        return {"floor_us_per_step": 10.0, "floor_queries_us_per_step": 12.0, "stack_us_per_step": 60.0,
                "stack_vs_floor": 6.0, "stack_vs_floor_queries": 5.0, "detail": {"pairs": ["p"]}}

    monkeypatch.setattr(bench, "bench_physics_floor", floor)
    monkeypatch.setattr(bench, "bench_lockstep", lambda s, seed=0: {"rtf": 1.0, "tick_cost_us": {}})
    monkeypatch.setattr(bench, "bench_codec", lambda: {})
    monkeypatch.setattr(bench, "bench_bus_load", lambda s, seed=0: {})
    monkeypatch.setattr(bench, "bench_learning", lambda n, seed=0: {})
    import hil.bench.socketcan as socketcan

    monkeypatch.setattr(socketcan, "hil_availability", lambda: {"available": False})
    b = bench.run_bench(seconds=3.0, seed=4, floor_pairs=3)
    assert seen == {"seconds": 3.0, "seed": 4, "pairs": 3}
    assert b["floor_us_per_step"] == 10.0 and b["floor_queries_us_per_step"] == 12.0
    assert b["stack_us_per_step"] == 60.0 and b["stack_vs_floor"] == 6.0 and b["stack_vs_floor_queries"] == 5.0
    assert b["detail"]["physics_floor"] == {"pairs": ["p"]} and b["lockstep_rtf"] == 1.0
    assert not {"bare_physics_rtf", "lockstep_vs_bare"} & b.keys()


def test_the_recording_run_records_on_the_plant_every_part_of_the_leg_holds():
    """The recording harness's leg is built on the recording plant (its ``plant_class``): every part
    of the leg holds that one plant, built as the plant is, its construction not noted."""
    from firmware_sim.plant import RigPlant

    run = pf._learning_run(0, recording=True)
    fresh = RigPlant(run.ls.config.rig)
    try:
        plant = run.ls.plant
        assert type(plant) is pf._RecordingPlant
        leg = run.ls.leg
        assert leg.board.source is plant and run.tracker.plant is plant
        assert all(axis.motor.plant is plant for axis in leg.axes.values())
        assert plant._rec_ops == [[]] and plant._rec_torques == []
        assert plant._states == fresh._states  # the rest pose: reset's defaults reached the compiled plant
    finally:
        fresh.close()
        run.close()
