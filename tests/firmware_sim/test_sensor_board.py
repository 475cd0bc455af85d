"""Frame-level tests of the simulated sensor board (node 16) against the DBC layout."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.sensor_board import SensorBoard, SensorBoardConfig
from protocol.contract import BusContract
from tests.fakes import FakeSensorSource

C = BusContract.load()
RANGE = C.codec("SB_Range")
CONTACTS = C.codec("SB_Contacts")
HEARTBEAT = C.codec("SB_Heartbeat")


def make(seed=1, source=None, **cfg):
    source = source if source is not None else FakeSensorSource()
    return SensorBoard(SensorBoardConfig(**cfg), source, np.random.default_rng(seed)), source


def by_name(msgs, codec):
    out = []
    for m in msgs:
        assert not m.is_extended_id and not m.is_remote_frame
        if m.arbitration_id == codec.frame_id:
            assert len(m.data) == codec.dlc
            out.append(codec.decode(m.data))
    return out


def run(board, duration, dt=0.001, t0=0.0, on_step=None):
    frames = []
    for i in range(round(duration / dt)):
        t = t0 + i * dt
        if on_step is not None:
            on_step(t)
        frames.extend(board.due(t))
    return frames


def range_samples(board, n):
    """n consecutive SB_Range samples, calling due() only at the range instants."""
    period = board.config.range_period_s
    return [by_name(board.due(i * period), RANGE)[0] for i in range(n)]


def test_ids_and_node():
    board, _ = make()
    assert board.node_id == 16
    assert (RANGE.frame_id, CONTACTS.frame_id, HEARTBEAT.frame_id) == (0x208, 0x20A, 0x201)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"range_dropout_prob": 1.5},
        {"range_noise_m": -0.1},
        {"range_max_m": 70.0},
        {"range_max_m": 0.0},
        {"range_period_s": math.nan},
        {"fw_version": 256},
    ],
)
def test_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        SensorBoardConfig(**kwargs)


def test_cyclic_rates_over_one_second():
    board, _ = make()
    frames = run(board, 1.0)
    assert 49 <= len(by_name(frames, RANGE)) <= 51
    assert 199 <= len(by_name(frames, CONTACTS)) <= 201
    assert 9 <= len(by_name(frames, HEARTBEAT)) <= 11


def test_range_noise_statistics_match_configured_sigma():
    board, _ = make(seed=7, source=FakeSensorSource(range_value=1.2), range_noise_m=0.02, range_dropout_prob=0.0)
    samples = range_samples(board, 4000)
    assert all(s["Range_Valid"] == 1 for s in samples)
    values = np.array([s["Range"] for s in samples])
    assert values.mean() == pytest.approx(1.2, abs=0.002)
    assert values.std(ddof=1) == pytest.approx(0.02, rel=0.05)


def test_zero_noise_reports_true_range_to_the_millimetre():
    board, _ = make(source=FakeSensorSource(range_value=0.8766), range_noise_m=0.0, range_dropout_prob=0.0)
    for s in range_samples(board, 20):
        assert s == {"Range": pytest.approx(0.877, abs=1e-9), "Range_Valid": 1, "Range_Seq": s["Range_Seq"]}


def test_dropout_rate_matches_configured_probability():
    board, _ = make(seed=3, range_dropout_prob=0.2)
    samples = range_samples(board, 5000)
    invalid = [s for s in samples if s["Range_Valid"] == 0]
    assert len(invalid) / len(samples) == pytest.approx(0.2, abs=0.03)
    assert all(s["Range"] == 0.0 for s in invalid)
    assert board.stats["range_invalid"] == len(invalid)


def test_no_hit_is_invalid():
    board, _ = make(source=FakeSensorSource(range_value=None), range_dropout_prob=0.0)
    samples = range_samples(board, 10)
    assert all(s["Range_Valid"] == 0 and s["Range"] == 0.0 for s in samples)


def test_readings_clipped_to_range():
    board, source = make(source=FakeSensorSource(range_value=2.99), range_noise_m=0.5, range_dropout_prob=0.0)
    high = range_samples(board, 300)
    source.range_value = 0.01
    low = [by_name(board.due(6.0 + i * 0.02), RANGE)[0] for i in range(300)]
    values = [s["Range"] for s in high + low]
    assert min(values) == 0.0 and max(values) == pytest.approx(3.0)
    assert all(0.0 <= v <= 3.0 + 1e-9 for v in values)


def test_range_seq_wraps_at_256():
    board, _ = make(range_dropout_prob=0.5)
    seqs = [s["Range_Seq"] for s in range_samples(board, 600)]
    assert seqs == [i % 256 for i in range(600)]


def test_contacts_seq_wraps_at_256():
    board, _ = make()
    seqs = [s["Contacts_Seq"] for s in by_name(run(board, 3.0), CONTACTS)]
    assert len(seqs) == 600
    assert seqs == [i % 256 for i in range(600)]


def test_contacts_sent_immediately_on_change():
    board, source = make()
    # 1 kHz steps from t=0.0001; cyclic frames at 0.0001 + k*5 ms; changes off that grid.
    changes = {0.0121: (True, False), 0.0161: (True, True), 0.0331: (False, False)}
    sent_at: list[tuple[float, dict]] = []
    for i in range(50):
        t = 0.0001 + i * 0.001
        for when, (foot, shin) in changes.items():
            if abs(t - when) < 1e-9:
                source.foot, source.shin = foot, shin
        for s in by_name(board.due(t), CONTACTS):
            sent_at.append((t, s))
    for when, (foot, shin) in changes.items():
        frames_then = [s for t, s in sent_at if abs(t - when) < 1e-9]
        assert len(frames_then) == 1, when
        assert (frames_then[0]["Foot_Contact"], frames_then[0]["Shin_Contact"]) == (foot, shin)
    seqs = [s["Contacts_Seq"] for _, s in sent_at]
    assert seqs == list(range(len(seqs)))  # change frames take a sequence number too
    assert len(sent_at) == 10 + 3  # 10 cyclic (every 5 ms over 50 ms) + 3 changes off the grid


def test_contact_change_still_sent_with_cyclic_disabled():
    board, source = make(contacts_period_s=0.0)
    assert len(by_name(board.due(0.0), CONTACTS)) == 1  # initial state
    assert by_name(board.due(0.001), CONTACTS) == []
    source.shin = True
    assert by_name(board.due(0.002), CONTACTS) == [{"Foot_Contact": 0, "Shin_Contact": 1, "Contacts_Seq": 1}]


def test_heartbeat_fields_and_uptime():
    board, _ = make(fw_version=7)
    hbs = by_name(run(board, 1.05), HEARTBEAT)
    assert len(hbs) == 11
    assert all(h["Board_Error"] == 0 and h["Board_State"] == 1 and h["Fw_Version"] == 7 for h in hbs)
    assert [h["Uptime_ds"] for h in hbs] == pytest.approx([i * 0.1 for i in range(11)])
    late = by_name(board.due(7000.0), HEARTBEAT)[0]  # 70000 ds wraps modulo 65536
    assert late["Uptime_ds"] == pytest.approx((70000 - 65536) * 0.1)


def test_rtr_replies_with_current_values():
    board, source = make(range_dropout_prob=0.0, range_noise_m=0.0)
    board.due(0.0)
    board.due(0.02)
    reply = board.handle(can.Message(arbitration_id=RANGE.frame_id, is_remote_frame=True, dlc=4, is_extended_id=False), 0.03)
    assert [RANGE.decode(m.data) for m in reply] == [{"Range": 1.0, "Range_Valid": 1, "Range_Seq": 1}]
    assert reply[0].arbitration_id == RANGE.frame_id and reply[0].dlc == RANGE.dlc
    source.foot = True
    reply = board.handle(can.Message(arbitration_id=CONTACTS.frame_id, is_remote_frame=True, dlc=3, is_extended_id=False), 0.03)
    assert [CONTACTS.decode(m.data) for m in reply] == [{"Foot_Contact": 1, "Shin_Contact": 0, "Contacts_Seq": 2}]
    assert by_name(board.due(0.021), CONTACTS) == []  # the reply already reported the change
    reply = board.handle(can.Message(arbitration_id=HEARTBEAT.frame_id, is_remote_frame=True, is_extended_id=False), 2.5)
    assert HEARTBEAT.decode(reply[0].data)["Uptime_ds"] == pytest.approx(2.5)
    assert board.stats["rx"] == {"SB_Heartbeat": 1, "SB_Range": 1, "SB_Contacts": 1, "SB_Profile": 0}


def test_other_frames_counted_and_ignored():
    board, _ = make()
    data_frame = can.Message(arbitration_id=RANGE.frame_id, data=b"\0\0\0\0", is_extended_id=False)
    assert board.handle(data_frame, 0.0) == []
    assert board.stats["malformed"] == 1
    assert board.handle(can.Message(arbitration_id=0x203, is_remote_frame=True, is_extended_id=False), 0.0) == []
    assert board.handle(can.Message(arbitration_id=0x208, is_remote_frame=True, is_extended_id=True), 0.0) == []
    assert board.stats["unknown"] == 2
    assert board.handle(can.Message(arbitration_id=0x028, is_remote_frame=True, is_extended_id=False), 0.0) == []
    assert board.stats["foreign"] == 1


def test_deterministic_for_a_seed():
    def trace(seed):
        board, _ = make(seed=seed, range_dropout_prob=0.3)
        return [(m.arbitration_id, bytes(m.data)) for m in run(board, 0.5)]

    assert trace(11) == trace(11)
    assert trace(11) != trace(12)


@settings(max_examples=300, deadline=None)
@given(
    frames=st.lists(
        st.tuples(
            st.one_of(st.integers(0x200, 0x21F), st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
            st.binary(max_size=8),
            st.booleans(),
            st.booleans(),
        ),
        max_size=25,
    )
)
def test_fuzzed_frames_never_raise(frames):
    board, _ = make()
    for i, (arb_id, data, remote, extended) in enumerate(frames):
        msg = can.Message(
            arbitration_id=arb_id,
            data=None if remote else data,
            dlc=len(data),
            is_remote_frame=remote,
            is_extended_id=extended or arb_id > 0x7FF,
        )
        for reply in board.handle(msg, i * 0.001):
            assert reply.arbitration_id >> 5 == 16 and not reply.is_remote_frame
    assert board.stats["internal_errors"] == 0
    assert sum(board.stats["tx"].values()) <= len(frames)
