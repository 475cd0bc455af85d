"""Gated memory, synaptic traces, the premotor output and the learning rule; the weights file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.stepping.learner import AdaptivePremotor, GatedMemory, LearnerConfig, SynapticTraces
from controller.stepping.weights import WeightsError, load_weights, save_weights


def test_memory_holds_the_gated_cell_and_decays_exponentially():
    m = GatedMemory(tau_s=0.5)
    assert m.activity(1.0) == 0.0
    m.gate(7, 1.0)
    assert m.activity(1.0) == pytest.approx(1.0)
    assert m.activity(1.5) == pytest.approx(math.exp(-1.0))
    m.gate(None, 2.0)  # nothing in view: the memory is cleared
    assert m.activity(2.1) == 0.0


def test_traces_decay_and_accumulate():
    tr = SynapticTraces(5, tau_s=2.0)
    tr.activate(1, 0.0)
    tr.activate(1, 2.0)
    assert tr.at(2.0)[1] == pytest.approx(1.0 + math.exp(-1.0))
    assert tr.at(4.0)[1] == pytest.approx((1.0 + math.exp(-1.0)) * math.exp(-1.0))
    assert tr.at(4.0)[0] == 0.0


def test_burst_is_base_plus_weighted_memory_and_relaxes_to_base():
    p = AdaptivePremotor(10, 0.3, LearnerConfig(stm_tau_s=1.0), weights=np.arange(10) * 0.01)
    p.on_step_onset(0.0, 4)
    assert p.burst_s(0.0) == pytest.approx(0.34)
    assert p.burst_s(1.0) == pytest.approx(0.3 + 0.04 * math.exp(-1.0))
    assert p.gated_weight() == pytest.approx(0.04)
    p.on_step_onset(2.0, None)
    assert p.burst_s(2.0) == 0.3 and p.gated_weight() == 0.0


def test_with_relax_out_of_view_the_burst_decays_on_after_the_obstacle_until_the_floor():
    from controller.stepping.learner import RELAX_FLOOR

    p = AdaptivePremotor(10, 0.3, LearnerConfig(stm_tau_s=1.0, relax_out_of_view=True), weights=np.arange(10) * 0.01)
    p.on_step_onset(0.0, 4)
    p.on_step_onset(0.8, None)  # the obstacle out of view: the memory decays on, no step down
    assert p.burst_s(1.5) == pytest.approx(0.3 + 0.04 * math.exp(-1.5)) and p.gated_weight() == pytest.approx(0.04)
    before = p.traces.at(0.8).copy()
    p.on_step_onset(0.8, None)
    assert np.array_equal(p.traces.at(0.8), before)  # a gate that sees nothing adds no trace
    p.on_step_onset(2.0, 6)  # a target again: it replaces the memory as any gate does
    assert p.burst_s(2.0) == pytest.approx(0.36)
    late = 2.0 - math.log(RELAX_FLOOR) + 0.01  # past the floor: the next empty gate clears it
    p.on_step_onset(late - 0.02, None)
    assert p.gated_weight() == pytest.approx(0.06)
    p.on_step_onset(late, None)
    assert p.burst_s(late) == 0.3 and p.gated_weight() == 0.0
    off = AdaptivePremotor(10, 0.3, LearnerConfig(stm_tau_s=1.0), weights=np.arange(10) * 0.01)
    off.on_step_onset(0.0, 4)
    off.on_step_onset(0.8, None)  # the default: cleared at once (the reproduction's behaviour)
    assert off.burst_s(0.9) == 0.3


def test_burst_is_exactly_base_plus_modulation_gated_or_not():
    """burst_s skips the modulation's calls when nothing is held: still exactly base + modulation_s."""
    p = AdaptivePremotor(4, 0.3, weights=np.array([0.0, 0.1, -0.2, 0.05]))
    for t, cell in [(0.0, None), (0.5, 1), (0.9, None), (1.0, 2), (1.7, 0), (2.2, 3), (2.3, None)]:
        p.on_step_onset(t, cell)
        for now in (t, t + 0.013, t + 0.4):
            assert p.burst_s(now) == p.base_burst_s + p.modulation_s(now)
            assert (p.burst_s(now) == 0.3) == (cell is None or cell == 0)


def test_extension_lengthens_placement_shortens_in_proportion_to_the_traces():
    cfg = LearnerConfig(learning_rate_s=0.1, trace_tau_s=1.0)
    p = AdaptivePremotor(10, 0.3, cfg)
    p.on_step_onset(0.0, 2)
    p.on_step_onset(1.0, 5)
    p.on_reflex("extension", 1.0)
    assert p.weights[5] == pytest.approx(0.1)
    assert p.weights[2] == pytest.approx(0.1 * math.exp(-1.0))
    assert np.count_nonzero(p.weights) == 2
    p.on_reflex("placement", 2.0)
    assert p.weights[5] == pytest.approx(0.1 - 0.1 * math.exp(-1.0))
    with pytest.raises(ValueError):
        p.on_reflex("sneeze", 3.0)


def test_weights_are_bounded_and_frozen_without_learning():
    p = AdaptivePremotor(4, 0.3, LearnerConfig(learning_rate_s=1.0, weight_limit_s=0.25))
    p.on_step_onset(0.0, 1)
    for _ in range(5):
        p.on_reflex("extension", 0.0)
    assert p.weights[1] == 0.25
    frozen = AdaptivePremotor(4, 0.3, LearnerConfig(learning=False))
    frozen.on_step_onset(0.0, 1)
    frozen.on_reflex("extension", 0.0)
    assert not frozen.weights.any()


def test_bad_weights_or_config_are_refused():
    with pytest.raises(ValueError):
        AdaptivePremotor(4, 0.3, weights=np.zeros(5))
    with pytest.raises(ValueError):
        AdaptivePremotor(4, 0.3, weights=np.array([0.0, math.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="stm_tau_s"):
        LearnerConfig(stm_tau_s=0.0)


def test_weights_file_round_trips_without_pickle(tmp_path):
    path = tmp_path / "w.npz"
    w = np.linspace(-0.2, 0.2, 75)
    save_weights(path, w, 0.04)
    assert np.array_equal(load_weights(path, 75, 0.04), w)
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {"weights", "cell_width_m", "schema_version", "checksum", "project_version"}
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda p: None, "no such"),
        (lambda p: p.write_bytes(b"PK\x03\x04 garbage"), "not a readable"),
        (lambda p: np.savez(p, weights=np.zeros(74), cell_width_m=0.04), r"\(74,\) weights"),
        (lambda p: np.savez(p, weights=np.zeros(75), cell_width_m=0.02), "cell width"),
        (lambda p: np.savez(p, weights=np.full(75, np.nan), cell_width_m=0.04), "NaN"),
        (lambda p: np.savez(p, weights=np.array([object()] * 75), cell_width_m=0.04), "not a readable"),
    ],
)
def test_missing_corrupt_or_mismatched_weights_give_a_clear_error(tmp_path, make, match):
    path = tmp_path / "w.npz"
    make(path)
    with pytest.raises(WeightsError, match=match):
        load_weights(path, 75, 0.04)
