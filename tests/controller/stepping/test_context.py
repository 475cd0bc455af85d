"""Height as context: the range profile from the plant's beams through the sensor board,
the bus and the height estimator to the context learner, and a short run end to end."""

from __future__ import annotations

import math
import uuid

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.config import ControllerConfig
from controller.stepping.context import ContextPremotor
from controller.stepping.height import HeightEstimator, HeightEstimatorConfig
from controller.stepping.learner import LearnerConfig
from controller.loop import ControlLoop
from controller.stepping.weights import WeightsError, load_weights, save_weights
from firmware_sim.plant import Obstacle, RigConfig, RigPlant
from firmware_sim.sensor_board import SensorBoard, SensorBoardConfig
from protocol import BusContract, data_frame
from tests.fakes import FakeSensorSource

C = BusContract.load()
PROFILE = C.codec("SB_Profile")
RANGE = C.codec("SB_Range")
NO_RETURN = 65.535


# -- plant: the beams' geometry ---------------------------------------------------------------
@pytest.fixture(scope="module")
def plant():
    p = RigPlant(RigConfig())
    yield p
    p.close()


@pytest.mark.parametrize("height_m,seen", [(0.04, 0), (0.06, 1), (0.10, 2), (0.12, 2), (0.15, 3)])
def test_an_obstacle_stops_the_beams_below_its_top_only(plant, height_m, seen):
    plant.clear_obstacles()
    sensor_x = plant.carriage_x_m + plant.config.sensor_offset_x_m
    plant.add_obstacle(Obstacle(sensor_x + 1.3, height_m))
    try:
        profile = plant.range_profile_m()
    finally:
        plant.clear_obstacles()
    assert len(profile) == 3
    assert [d is not None for d in profile] == [i < seen for i in range(3)]
    for d in profile[:seen]:
        assert d == pytest.approx(1.3, abs=1e-6)


def test_no_obstacle_or_one_beyond_3_m_gives_no_return(plant):
    plant.clear_obstacles()
    assert plant.range_profile_m() == (None, None, None)  # horizontal beams never meet the ground
    plant.add_obstacle(Obstacle(plant.carriage_x_m + plant.config.sensor_offset_x_m + 3.05, 0.15))
    try:
        assert plant.range_profile_m() == (None, None, None)
    finally:
        plant.clear_obstacles()


@pytest.mark.parametrize("heights", [(0.05, 0.05), (0.09, 0.05), (0.0,), (0.05, 0.09, 0.13, 0.17), (math.nan,)])
def test_bad_beam_heights_are_refused(heights):
    with pytest.raises(ValueError, match="profile_heights_m"):
        RigConfig(profile_heights_m=heights)


# -- sensor board: SB_Profile --------------------------------------------------------------------
def board(seed=1, profile=(1.0, None, None), **cfg):
    source = FakeSensorSource(range_value=1.0, profile_value=profile)
    return SensorBoard(SensorBoardConfig(**cfg), source, np.random.default_rng(seed)), source


def decoded(frames, codec):
    return [codec.decode(m.data) for m in frames if m.arbitration_id == codec.frame_id and len(m.data) == codec.dlc]


def test_profile_frame_id_layout_and_rate():
    assert (PROFILE.frame_id, PROFILE.dlc, PROFILE.compiled) == (0x209, 7, True)
    assert C.cycle_time_s("SB_Profile") == C.cycle_time_s("SB_Range")
    b, _ = board()
    frames = [m for i in range(1000) for m in b.due(i * 0.001)]
    profiles, ranges = decoded(frames, PROFILE), decoded(frames, RANGE)
    assert len(profiles) == len(ranges) == 50
    assert [p["Profile_Seq"] for p in profiles] == list(range(50))


def test_profile_values_no_return_and_unfitted_slots():
    b, source = board(profile=(0.8766, 0.9, None), range_noise_m=0.0, range_dropout_prob=0.0)
    p = decoded(b.due(0.0), PROFILE)[0]
    assert p["Beam_0"] == pytest.approx(0.877) and p["Beam_1"] == pytest.approx(0.9)
    assert p["Beam_2"] == pytest.approx(NO_RETURN)
    source.profile_value = (1.5,)  # a rig with one beam: the other slots are "no return"
    p = decoded(b.due(0.02), PROFILE)[0]
    assert (p["Beam_0"], p["Beam_1"], p["Beam_2"]) == pytest.approx((1.5, NO_RETURN, NO_RETURN))
    assert bytes(PROFILE.pack(1.5, NO_RETURN, NO_RETURN, 0))[2:6] == b"\xff\xff\xff\xff"


def test_profile_noise_and_dropout_follow_the_range_model():
    b, _ = board(seed=5, profile=(1.2, 1.2, 1.2), range_noise_m=0.02, range_dropout_prob=0.2)
    samples = [decoded(b.due(i * 0.02), PROFILE)[0] for i in range(3000)]
    values = np.array([[s[f"Beam_{k}"] for k in range(3)] for s in samples])
    dropped = values == NO_RETURN
    assert dropped.mean() == pytest.approx(0.2, abs=0.02)
    kept = values[~dropped]
    assert kept.mean() == pytest.approx(1.2, abs=0.002)
    assert kept.std(ddof=1) == pytest.approx(0.02, rel=0.06)


def test_the_profile_never_changes_the_range_samples():
    def ranges(enabled):
        b, _ = board(seed=9, range_dropout_prob=0.3, profile_enabled=enabled)
        return [bytes(m.data) for i in range(200) for m in b.due(i * 0.02) if m.arbitration_id == RANGE.frame_id]

    assert ranges(True) == ranges(False)
    b, _ = board(profile_enabled=False)
    assert decoded(b.due(0.0), PROFILE) == []


def test_profile_rtr_reply_and_too_many_beams():
    b, source = board(range_noise_m=0.0, range_dropout_prob=0.0)
    b.due(0.0)
    rtr = can.Message(arbitration_id=PROFILE.frame_id, is_remote_frame=True, dlc=7, is_extended_id=False)
    reply = b.handle(rtr, 0.01)
    assert [PROFILE.decode(m.data) for m in reply] == [
        {"Beam_0": 1.0, "Beam_1": pytest.approx(NO_RETURN), "Beam_2": pytest.approx(NO_RETURN), "Profile_Seq": 0}
    ]
    assert b.stats["rx"]["SB_Profile"] == 1
    source.profile_value = (1.0, 1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="4 profile beams"):
        b.due(0.02)


@settings(max_examples=100, deadline=None)
@given(beams=st.lists(st.integers(0, 0xFFFF), min_size=3, max_size=3), seq=st.integers(0, 255))
def test_profile_codec_matches_cantools(beams, seq):
    values = [b * 0.001 for b in beams]
    ours = PROFILE.pack(*values, seq)
    assert ours == PROFILE.message.encode(dict(zip(PROFILE.signal_names, [*values, seq])))
    assert ours == b"".join(b.to_bytes(2, "little") for b in beams) + bytes([seq])


# -- controller: decode and validate ---------------------------------------------------------
@pytest.fixture
def loop():
    channel = f"test-{uuid.uuid4().hex}"
    ours = can.Bus(interface="virtual", channel=channel)
    theirs = can.Bus(interface="virtual", channel=channel)
    yield ControlLoop(ControllerConfig(), ours), theirs
    ours.shutdown()
    theirs.shutdown()


def profile_frame(b0, b1, b2, seq):
    return data_frame(PROFILE.frame_id, PROFILE.pack(b0, b1, b2, seq))


def test_controller_decodes_the_profile_and_drops_bad_frames(loop):
    ctl, theirs = loop
    theirs.send(profile_frame(1.234, 1.25, NO_RETURN, 0))
    ctl.io.drain(0.0)
    assert ctl.sensors.profile_m == (pytest.approx(1.234), pytest.approx(1.25), None)
    assert ctl.io.rx["SB_Profile"] == 1
    bad = [
        can.Message(arbitration_id=PROFILE.frame_id, data=b"\x00" * 6, is_extended_id=False),  # short DLC
        profile_frame(1.0, 10.0, NO_RETURN, 1),  # 10 m: beyond the beams' 3 m reach, not "no return"
        profile_frame(1.0, 1.0, 1.0, 0),  # sequence number did not advance
    ]
    for msg in bad:
        theirs.send(msg)
    theirs.send(profile_frame(1.1, NO_RETURN, NO_RETURN, 3))  # seq 1 and 2 lost
    ctl.io.drain(0.01)
    assert ctl.io.dropped["malformed"] == 1 and ctl.io.dropped["invalid"] == 2
    assert ctl.sensors.profile_m == (pytest.approx(1.1), None, None)
    assert (ctl.sensors.profile_samples, ctl.sensors.profile_lost) == (2, 2)
    assert (ctl.sensors.profile_invalid, ctl.sensors.profile_out_of_sequence) == (1, 1)


def test_nan_profile_is_invalid_not_raised():
    from controller.io.sensors import SensorLink

    s = SensorLink(16)
    assert not s.on_profile((math.nan, 1.0, 1.0, 0), 0.0)
    assert not s.on_profile((-0.5, 1.0, 1.0, 0), 0.0)
    assert s.profile_invalid == 2 and s.profile_samples == 0
    with pytest.raises(ValueError, match="profile_max_m"):
        SensorLink(16, profile_max_m=0.0)


# -- height estimator ---------------------------------------------------------------------------
def test_context_counts_the_beams_on_the_target():
    h = HeightEstimator()
    assert h.context is None
    h.update((1.0, None, None), 1.01)
    assert h.context == 1
    h.clear()
    h.update((1.0, 1.02, 2.5), 1.0)  # the top beam sees something farther: not the target
    assert h.context == 2
    assert h.beams_on_target((1.0, 1.0, 1.0), 1.5) == (False, False, False)
    assert h.beams_on_target((1.0,), 1.0) == (True, False, False)


def test_majority_over_recent_samples_survives_dropouts_and_resets_with_the_target():
    h = HeightEstimator(HeightEstimatorConfig(window=10))
    rng = np.random.default_rng(0)
    raw_right = estimate_right = 0
    n = 100
    for i in range(n):
        r = 2.0 - 0.01 * i
        # an obstacle between the 0.09 and 0.13 m beams, each beam dropping out 20% of the time
        profile = tuple(None if rng.random() < 0.2 else r + 0.02 * rng.standard_normal() for _ in range(2)) + (None,)
        h.update(profile, r)
        raw_right += sum(h.beams_on_target(profile, r)) == 2
        estimate_right += h.context == 2
    assert raw_right / n < 0.75  # one sample alone is often wrong (0.8^2 = 0.64 expected) ...
    assert estimate_right / n >= 0.95  # ... the majority over the recent samples almost never
    h.update((0.91, None, None), 0.91)  # the filter moved by 0.1 m: the same target, one vote among ten
    assert h.context == 2
    h.update((0.4, None, None), 0.4)  # a jump of 0.5 m: a new target, the old votes go
    assert h.context == 1
    h.update((0.8, 0.8, 0.8), None)  # no target in view
    assert h.context is None


def test_a_beam_counts_when_it_saw_the_target_in_the_required_fraction_and_bounds():
    h = HeightEstimator(HeightEstimatorConfig(window=4))
    for profile in [(1.0, 1.0, None), (1.0, None, None), (1.0, 1.0, 1.0), (1.0, None, None)]:
        h.update(profile, 1.0)
    assert h.context == 2  # beam 1 in 2 of 4 (a tie counts), beam 2 in 1 of 4
    strict = HeightEstimator(HeightEstimatorConfig(window=4, seen_fraction=0.75))
    for profile in [(1.0, 1.0, None), (1.0, None, None), (1.0, 1.0, 1.0), (1.0, None, None)]:
        strict.update(profile, 1.0)
    assert strict.context == 1
    assert h.bounds_m(0) == (0.0, 0.05) and h.bounds_m(2) == (0.09, 0.13) and h.bounds_m(3) == (0.13, math.inf)
    with pytest.raises(ValueError):
        h.bounds_m(4)


@pytest.mark.parametrize("kwargs", [{"beam_heights_m": ()}, {"beam_heights_m": (0.1, 0.05)}, {"window": 0},
                                    {"match_tolerance_m": 0.0}, {"jump_m": math.nan},
                                    {"seen_fraction": 0.0}])
def test_bad_height_config_is_refused(kwargs):
    with pytest.raises(ValueError, match="height."):
        HeightEstimatorConfig(**kwargs)


# -- context premotor -----------------------------------------------------------------------------
def test_the_context_selects_the_weight_row():
    w = np.zeros((4, 10))
    w[1, 3], w[2, 3] = 0.05, -0.08
    p = ContextPremotor(4, 10, 0.3, LearnerConfig(stm_tau_s=1.0), weights=w)
    p.on_step_onset(0.0, 3, context=1)
    assert p.burst_s(0.0) == pytest.approx(0.35) and p.gated_weight() == pytest.approx(0.05)
    p.on_step_onset(1.0, 3, context=2)
    assert p.burst_s(2.0) == pytest.approx(0.3 - 0.08 * math.exp(-1.0))
    p.on_step_onset(3.0, 3)  # unknown height: the row of "no beam on the target"
    assert p.gated_weight() == 0.0
    p.on_step_onset(4.0, None, context=2)
    assert p.burst_s(4.0) == 0.3 and p.gated_weight() == 0.0
    with pytest.raises(ValueError, match="context"):
        p.on_step_onset(5.0, 3, context=4)


def test_a_reflex_in_one_context_leaves_the_other_contexts_alone():
    cfg = LearnerConfig(learning_rate_s=0.1, trace_tau_s=1.0)
    p = ContextPremotor(3, 10, 0.3, cfg)
    p.on_step_onset(0.0, 2, context=1)
    p.on_step_onset(1.0, 5, context=1)
    p.on_reflex("extension", 1.0)
    assert p.weights[1, 5] == pytest.approx(0.1)
    assert p.weights[1, 2] == pytest.approx(0.1 * math.exp(-1.0))
    assert not p.weights[0].any() and not p.weights[2].any()
    # the same cells in context 2: only context 2's synapses are new; context 1's decay
    p.on_step_onset(10.0, 5, context=2)
    before = p.weights[1].copy()
    p.on_reflex("placement", 10.0)
    assert p.weights[2, 5] == pytest.approx(-0.1)
    np.testing.assert_allclose(p.weights[1], before - 0.1 * p.traces.at(10.0).reshape(3, 10)[1], atol=1e-12)
    assert np.abs(p.weights[1] - before).max() < 1e-4  # traces of 9 s ago: e^-9 of their peak
    assert not p.weights[0].any()


def test_context_premotor_bounds_freezing_and_bad_weights():
    p = ContextPremotor(2, 4, 0.3, LearnerConfig(learning_rate_s=1.0, weight_limit_s=0.25))
    p.on_step_onset(0.0, 1, context=1)
    for _ in range(5):
        p.on_reflex("extension", 0.0)
    assert p.weights[1, 1] == 0.25
    frozen = ContextPremotor(2, 4, 0.3, LearnerConfig(learning=False))
    frozen.on_step_onset(0.0, 1, context=1)
    frozen.on_reflex("extension", 0.0)
    assert not frozen.weights.any()
    with pytest.raises(ValueError, match="weights"):
        ContextPremotor(2, 4, 0.3, weights=np.zeros(4))
    with pytest.raises(ValueError, match="n_contexts"):
        ContextPremotor(0, 4, 0.3)
    with pytest.raises(ValueError, match="reflex"):
        p.on_reflex("sneeze", 1.0)


# -- weights file ---------------------------------------------------------------------------------
def test_two_dimensional_weights_round_trip_and_are_checked(tmp_path):
    path = tmp_path / "w.npz"
    w = np.linspace(-0.2, 0.2, 4 * 28).reshape(4, 28)
    save_weights(path, w, 0.04)
    assert np.array_equal(load_weights(path, 28, 0.04, n_contexts=4), w)
    with pytest.raises(WeightsError, match=r"\(4, 28\) weights, this controller has 28 cells"):
        load_weights(path, 28, 0.04)
    with pytest.raises(WeightsError, match="3 contexts"):
        load_weights(path, 28, 0.04, n_contexts=3)
    save_weights(path, w[0], 0.04)
    with pytest.raises(WeightsError, match="4 contexts"):
        load_weights(path, 28, 0.04, n_contexts=4)
    with pytest.raises(ValueError, match="1-D or 2-D"):
        save_weights(path, np.zeros((2, 2, 2)), 0.04)


# -- end to end -------------------------------------------------------------------------------------
def test_context_run_gates_different_contexts_for_different_heights():
    from hil.experiments.learn import run_method

    metrics = run_method("context", seed=0, trials=3, obstacle_height_m=(0.06, 0.12))
    by_height: dict[float, list[int | None]] = {}
    for t in metrics["trials"]:
        assert len(t["gated_contexts"]) == len(t["gated_cells"])
        by_height.setdefault(t["obstacle_height_m"], []).extend(
            c for c, cell in zip(t["gated_contexts"], t["gated_cells"]) if cell is not None)
    assert set(by_height) == {0.06, 0.12}, "seed 0 must draw both heights in 3 trials"
    low, high = by_height[0.06], by_height[0.12]
    assert low and high
    assert max(set(low), key=low.count) == 1  # 0.06 m: only the 0.05 m beam sees it
    assert max(set(high), key=high.count) == 2  # 0.12 m: the 0.05 and 0.09 m beams
    assert set(low).isdisjoint(high)
