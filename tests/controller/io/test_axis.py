"""AxisLink's command clamp (every joint target passes through it) and its feedback handlers:
what reaches the wire for each target, and what each reading changes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.config import default_axes
from controller.io.axis import AxisConfig, AxisLink, FeedbackLimits
from protocol import AxisState, BusContract

C = BusContract.load()
POS = C.codec("Set_Input_Pos")
F32_REL = 1e-6  # the frame carries a float32


def hip() -> AxisLink:
    return AxisLink(default_axes()[0], C)  # [-0.75, 1.25] rad, gear 6, direction +1


def knee() -> AxisLink:
    return AxisLink(default_axes()[1], C)  # [-2.15, 0] rad, gear 6, direction -1


def sent_rad(link: AxisLink, frame) -> float:
    """The joint angle [rad] a Set_Input_Pos frame commands."""
    assert frame.arbitration_id == link.pos_id and len(frame.data) == POS.dlc
    return link.config.rev_to_rad(POS.unpack(frame.data)[0])


# --------------------------------------------------------------------------- the clamp
@pytest.mark.parametrize("make", [hip, knee], ids=["hip", "knee"])
@pytest.mark.parametrize("bad", [math.nan, -math.nan, math.inf, -math.inf], ids=["nan", "-nan", "inf", "-inf"])
def test_a_non_finite_target_holds_the_last_target_never_a_limit(make, bad):
    link = make()
    link.pos_rad = -0.4  # measured: not what is held when there is a last target
    target = -0.3
    assert sent_rad(link, link.pos_frame(target)) == pytest.approx(target, rel=F32_REL)
    assert link.clamped_targets == 0
    for k in range(1, 4):  # held however many come, each counted
        q = sent_rad(link, link.pos_frame(bad))
        assert q == pytest.approx(target, rel=F32_REL), (bad, q)
        assert link.last_target_rad == target and link.clamped_targets == k


@pytest.mark.parametrize("make", [hip, knee], ids=["hip", "knee"])
def test_a_nan_first_target_holds_the_measured_position_clamped_into_the_limits(make):
    link = make()
    cfg = link.config
    link.pos_rad = -0.5  # inside both ranges
    assert sent_rad(link, link.pos_frame(math.nan)) == pytest.approx(-0.5, rel=F32_REL)
    assert link.last_target_rad == -0.5 and link.clamped_targets == 1
    link = make()
    link.pos_rad = cfg.max_rad + 0.3  # a reading past the limit (within the feedback slack)
    assert sent_rad(link, link.pos_frame(math.nan)) == pytest.approx(cfg.max_rad, abs=1e-6)
    link = make()
    link.pos_rad = cfg.min_rad - 0.3
    assert sent_rad(link, link.pos_frame(math.nan)) == pytest.approx(cfg.min_rad, abs=1e-6)


def test_with_no_target_and_no_reading_a_nan_target_is_zero_clamped_into_the_limits():
    assert sent_rad(hip(), hip().pos_frame(math.nan)) == 0.0  # 0 lies inside [-0.75, 1.25]
    above = AxisLink(AxisConfig("hip", node_id=0, min_rad=0.5, max_rad=1.0), C)
    assert above.clamp(math.nan) == 0.5 and above.clamped_targets == 1
    below = AxisLink(AxisConfig("knee", node_id=1, min_rad=-1.0, max_rad=-0.5, direction=-1), C)
    assert below.clamp(math.nan) == -0.5 and below.clamped_targets == 1


@pytest.mark.parametrize("make", [hip, knee], ids=["hip", "knee"])
def test_a_finite_target_outside_the_limits_goes_to_the_nearest_limit_and_is_counted(make):
    link = make()
    cfg = link.config
    assert link.clamp(cfg.max_rad + 1e-9) == cfg.max_rad and link.clamped_targets == 1
    assert link.clamp(cfg.min_rad - 1e-9) == cfg.min_rad and link.clamped_targets == 2
    assert link.clamp(1e300) == cfg.max_rad and link.clamp(-1e300) == cfg.min_rad and link.clamped_targets == 4
    for q in (cfg.min_rad, cfg.max_rad, 0.5 * (cfg.min_rad + cfg.max_rad)):  # inside: unchanged, not counted
        assert link.clamp(q) == q
    assert link.clamped_targets == 4
    assert sent_rad(link, link.pos_frame(cfg.max_rad + 2.0)) == pytest.approx(cfg.max_rad, abs=1e-6)
    assert link.last_target_rad == cfg.max_rad


def test_the_velocity_feed_forward_is_converted_clamped_and_zero_when_not_finite():
    link = knee()  # direction -1: a joint speed of +1 rad/s is -6/(2 pi) rev/s at the motor
    _, vel, torque = POS.unpack(link.pos_frame(-1.0, 1.0).data)
    assert vel == pytest.approx(-6.0 / (2 * math.pi), abs=0.001) and torque == 0.0  # Vel_FF: steps of 0.001
    assert POS.unpack(link.pos_frame(-1.0, 1e6).data)[1] == -32.0
    assert POS.unpack(link.pos_frame(-1.0, -1e6).data)[1] == 32.0
    for bad in (math.nan, math.inf, -math.inf):
        assert POS.unpack(link.pos_frame(-1.0, bad).data)[1] == 0.0


# --------------------------------------------------------------------------- feedback
def test_an_encoder_reading_is_applied_whole_in_joint_units_or_not_at_all():
    link = knee()
    assert link.on_encoder((1.2, 3.0), 0.5)
    assert link.pos_rad == pytest.approx(-1.2 * 2 * math.pi / 6.0) and link.encoder_t_s == 0.5
    assert link.vel_rad_s == pytest.approx(-3.0 * 2 * math.pi / 6.0)
    state = (link.pos_rad, link.vel_rad_s, link.encoder_t_s)
    for bad in ((1.2, math.nan), (math.nan, 0.0), (1.2, 100.001), (1.2, -100.001), (math.inf, 0.0)):
        assert not link.on_encoder(bad, 0.6), bad
        assert (link.pos_rad, link.vel_rad_s, link.encoder_t_s) == state
    assert link.on_encoder((1.2, 100.0), 0.6) and link.on_encoder((1.2, -100.0), 0.7)  # the bound itself


def test_the_position_slack_bounds_a_reading_on_both_sides():
    limits = FeedbackLimits(pos_slack_rad=0.2)
    cfg = default_axes()[0]  # hip: [-0.75, 1.25] rad; 1 rad = 6/(2 pi) rev
    rev = lambda q: q * 6.0 / (2 * math.pi)  # noqa: E731
    for q, ok in ((1.25 + 0.19, True), (1.25 + 0.21, False), (-0.75 - 0.19, True), (-0.75 - 0.21, False)):
        link = AxisLink(cfg, C, limits)
        assert link.on_encoder((rev(q), 0.0), 0.0) is ok, q


def test_the_jump_bound_uses_the_time_since_the_last_reading_and_its_floor():
    limits = FeedbackLimits(max_joint_speed_rad_s=10.0, min_jump_dt_s=0.01, jump_slack_rad=0.02)
    rev = lambda q: q * 6.0 / (2 * math.pi)  # noqa: E731
    link = AxisLink(default_axes()[0], C, limits)
    assert link.on_encoder((rev(0.0), 0.0), 1.0)
    # 0.5 s later: up to 10 * 0.5 + 0.02 = 5.02 rad (the range allows 1.25)
    assert link.on_encoder((rev(1.0), 0.0), 1.5)
    # the same instant: the floor 0.01 s -> up to 0.12 rad
    assert link.on_encoder((rev(1.11), 0.0), 1.5) and not link.on_encoder((rev(1.11 + 0.13), 0.0), 1.5)
    assert link.pos_rad == pytest.approx(1.11)
    # 0.1 s later: up to 1.02 rad
    assert not link.on_encoder((rev(1.11 - 1.03), 0.0), 1.6) and link.on_encoder((rev(1.11 - 1.01), 0.0), 1.6)


def test_feedback_limits_refuse_non_positive_or_non_finite_values():
    for name in ("max_vel_rev_s", "pos_slack_rad", "max_joint_speed_rad_s", "min_jump_dt_s", "jump_slack_rad"):
        for bad in (0.0, -1.0, math.nan, math.inf, "1"):
            with pytest.raises(ValueError, match=f"FeedbackLimits.{name} must be finite and > 0"):
                FeedbackLimits(**{name: bad})


def test_a_heartbeat_applies_state_error_and_result_together_or_nothing():
    link = hip()
    assert link.on_heartbeat((0x2000000, int(AxisState.IDLE), 3, 1), 0.2)
    assert (link.error, link.state, link.procedure_result, link.heartbeat_t_s) == (0x2000000, AxisState.IDLE, 3, 0.2)
    assert not link.closed_loop
    assert link.on_heartbeat((0, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.3) and link.closed_loop
    assert not link.on_heartbeat((0, 99, 0, 0), 0.4)
    assert not link.on_heartbeat((1 << 31, int(AxisState.IDLE), 0, 0), 0.4)
    assert (link.error, link.state, link.heartbeat_t_s) == (0, AxisState.CLOSED_LOOP_CONTROL, 0.3)
    assert link.on_heartbeat((0x1000000, int(AxisState.CLOSED_LOOP_CONTROL), 0, 0), 0.5) and not link.closed_loop


# --------------------------------------------------------------------------- the configuration and units
def test_an_axis_configuration_names_itself_in_its_errors_and_needs_min_below_max():
    with pytest.raises(ValueError, match=r"^axes\.knee: min_rad 0\.5 must be below max_rad 0\.5$"):
        AxisConfig("knee", node_id=1, min_rad=0.5, max_rad=0.5)
    with pytest.raises(ValueError, match=r"^axes\.knee\.gear_ratio "):
        AxisConfig("knee", node_id=1, min_rad=-1.0, max_rad=0.0, gear_ratio=0.0)
    AxisConfig("knee", node_id=1, min_rad=-1.0, max_rad=-0.999)  # any positive width is fine


@pytest.mark.parametrize("direction", [1, -1])
def test_joint_and_motor_velocities_convert_through_gear_and_direction(direction):
    cfg = AxisConfig("hip", node_id=0, min_rad=-1.0, max_rad=1.0, gear_ratio=8.0, direction=direction,
                     zero_offset_rev=3.0)  # an offset moves positions, never velocities
    assert cfg.rad_s_to_rev_s(math.pi) == pytest.approx(direction * 4.0)
    assert cfg.rev_s_to_rad_s(direction * 4.0) == pytest.approx(math.pi)
    assert cfg.rev_s_to_rad_s(1.0) == pytest.approx(direction * 2.0 * math.pi / 8.0)
    assert cfg.rad_to_rev(math.pi) == pytest.approx(3.0 + direction * 4.0)


# --------------------------------------------------------------------------- float32 bounds
def test_f32_step_moves_to_the_neighbouring_float32_either_way():
    from controller.io.axis import _f32_step

    tiny = 1.401298464324817e-45  # the smallest positive float32 (a subnormal)
    assert _f32_step(0.0, up=True) == tiny and _f32_step(0.0, up=False) == -tiny
    assert _f32_step(1.0, up=True) == 1.0 + 2.0 ** -23 and _f32_step(1.0, up=False) == 1.0 - 2.0 ** -24
    assert _f32_step(-1.0, up=False) == -1.0 - 2.0 ** -23 and _f32_step(-1.0, up=True) == -1.0 + 2.0 ** -24


def _f32_neighbour(x: float, up: bool) -> float:
    import numpy as np

    return float(np.nextafter(np.float32(x), np.float32(math.inf if up else -math.inf)))


@pytest.mark.parametrize("cfg", [
    AxisConfig("hip", node_id=0, min_rad=-0.75, max_rad=1.25),
    AxisConfig("knee", node_id=1, min_rad=-2.15, max_rad=0.0, direction=-1),
    AxisConfig("hip", node_id=0, min_rad=0.1, max_rad=0.3, gear_ratio=9.0, zero_offset_rev=-17.3),
    AxisConfig("knee", node_id=1, min_rad=-6.0, max_rad=6.0, gear_ratio=101.0, direction=-1, zero_offset_rev=999.0),
], ids=["hip", "knee", "offset", "wide"])
def test_the_target_bounds_are_the_outermost_float32_inside_the_range(cfg):
    from controller.io.axis import float32_target_bounds_rev

    lo, hi = float32_target_bounds_rev(cfg)
    inside = lambda rev: cfg.min_rad <= cfg.rev_to_rad(rev) <= cfg.max_rad  # noqa: E731
    assert inside(lo) and inside(hi) and lo < hi
    assert not inside(_f32_neighbour(lo, up=False)) and not inside(_f32_neighbour(hi, up=True))


def test_a_range_too_narrow_for_any_float32_is_refused_naming_the_axis():
    from controller.io.axis import float32_target_bounds_rev

    cfg = AxisConfig("knee", node_id=1, min_rad=1.0, max_rad=1.0 + 1e-12)  # float32 steps there: about 6e-8 rev
    with pytest.raises(ValueError, match=r"^axes\.knee: the range \[1\.0, 1\.000000000001\] rad holds no float32 "
                                         r"motor position$"):
        float32_target_bounds_rev(cfg)


# --------------------------------------------------------------------------- the other command frames
def test_the_command_frames_carry_their_ids_and_values():
    from protocol import ControlMode, InputMode

    cfg = AxisConfig("knee", node_id=5, min_rad=-1.0, max_rad=0.0, current_limit_a=12.5, vel_limit_rev_s=7.25)
    link = AxisLink(cfg, C)
    assert link.feedback_limits == FeedbackLimits()
    frames = {
        "Set_Axis_State": (link.state_frame(AxisState.CLOSED_LOOP_CONTROL), {"Axis_Requested_State": 8}),
        "Set_Controller_Mode": (link.mode_frame(ControlMode.POSITION_CONTROL, InputMode.PASSTHROUGH),
                                {"Control_Mode": 3, "Input_Mode": 1}),
        "Set_Limits": (link.limits_frame(), {"Velocity_Limit": 7.25, "Current_Limit": 12.5}),
        "Clear_Errors": (link.clear_errors_frame(), {"Identify": 0}),
    }
    for name, (frame, values) in frames.items():
        codec = C.codec(name)
        assert frame.arbitration_id == C.odrive_id(5, name) and len(frame.data) == codec.dlc, name
        assert codec.decode(frame.data) == values, name
    estop = link.estop_frame()
    assert estop.arbitration_id == C.odrive_id(5, "Estop") and bytes(estop.data) == b"" and estop.dlc == 0
    assert (link.state_id, link.mode_id, link.clear_id, link.limits_id, link.estop_id) == tuple(
        C.odrive_id(5, n) for n in ("Set_Axis_State", "Set_Controller_Mode", "Clear_Errors", "Set_Limits", "Estop"))


def test_sdo_frames_leave_the_reserved_byte_zero_and_replies_count_from_their_time():
    from protocol.contract import sdo_value_bits
    from protocol.endpoints import ENABLE_WATCHDOG, WATCHDOG_TIMEOUT

    link = AxisLink(AxisConfig("hip", node_id=2, min_rad=-1.0, max_rad=1.0), C)
    rx = C.codec("RxSdo")
    for frame in (link.sdo_write_frame(WATCHDOG_TIMEOUT, 0.25), link.sdo_read_frame(WATCHDOG_TIMEOUT),
                  link.sdo_write_frame(ENABLE_WATCHDOG, True)):
        assert frame.arbitration_id == link.rxsdo_id == C.odrive_id(2, "RxSdo")
        assert rx.decode(frame.data)["Reserved"] == 0
    assert rx.decode(link.sdo_write_frame(WATCHDOG_TIMEOUT, 0.25).data)["Value"] == sdo_value_bits(0.25)
    assert rx.decode(link.sdo_write_frame(ENABLE_WATCHDOG, True).data)["Value"] == 1
    assert link.txsdo_id == C.odrive_id(2, "TxSdo") and link.txsdo_codec is C.codec("TxSdo")
    assert link.on_txsdo((0, WATCHDOG_TIMEOUT.id, 0, sdo_value_bits(0.25)), 3.0)
    assert link.sdo_reply(WATCHDOG_TIMEOUT, since_s=3.0) == 0.25  # a reply at the very instant counts
    assert link.on_txsdo((0, ENABLE_WATCHDOG.id, 0, 1), 3.0)
    assert link.sdo_reply(ENABLE_WATCHDOG) is True


# --------------------------------------------------------------------------- health readings and reset
def test_bus_voltage_is_kept_from_0_to_100_v_with_a_finite_current():
    link = hip()
    for v in (0.0, 100.0, 24.0):
        assert link.on_bus_voltage((v, 1.5), v)
        assert link.bus_voltage_v == v and link.bus_voltage_t_s == v
    for bad in ((-0.001, 0.0), (100.001, 0.0), (math.nan, 0.0), (24.0, math.nan), (24.0, math.inf)):
        assert not link.on_bus_voltage(bad, 9.0)
    assert link.bus_voltage_v == 24.0 and link.bus_voltage_t_s == 24.0


def test_temperatures_are_kept_a_missing_thermistor_as_none_an_implausible_reading_not_at_all():
    link = hip()
    assert link.on_temperature((45.0, 60.0), 1.0)
    assert (link.fet_temp_c, link.motor_temp_c, link.temperature_t_s) == (45.0, 60.0, 1.0)
    assert link.on_temperature((math.nan, 61.0), 2.0)  # no FET thermistor
    assert (link.fet_temp_c, link.motor_temp_c, link.temperature_t_s) == (None, 61.0, 2.0)
    assert link.on_temperature((46.0, math.nan), 3.0)
    assert (link.fet_temp_c, link.motor_temp_c) == (46.0, None)
    assert link.on_temperature((-60.0, 300.0), 4.0) and (link.fet_temp_c, link.motor_temp_c) == (-60.0, 300.0)
    for bad in ((301.0, 50.0), (50.0, -61.0), (math.inf, 50.0), (50.0, -math.inf)):
        assert not link.on_temperature(bad, 5.0)
        assert (link.fet_temp_c, link.motor_temp_c, link.temperature_t_s) == (-60.0, 300.0, 4.0)


def test_the_measured_current_is_kept_when_finite():
    link = hip()
    assert link.iq_a is None and link.on_iq((9.0, -3.5), 1.0) and (link.iq_a, link.iq_t_s) == (-3.5, 1.0)
    for bad in (math.nan, math.inf):
        assert not link.on_iq((0.0, bad), 2.0) and (link.iq_a, link.iq_t_s) == (-3.5, 1.0)
    assert link.on_iq((math.nan, 2.0), 3.0) and link.iq_a == 2.0  # the setpoint is not checked


def test_reset_feedback_forgets_every_reading():
    link = hip()
    assert link.on_heartbeat((0x2000000, int(AxisState.IDLE), 2, 1), 1.0)
    assert link.on_encoder((0.5, 1.0), 1.0) and link.on_bus_voltage((24.0, 0.0), 1.0)
    assert link.on_temperature((40.0, 41.0), 1.0) and link.on_iq((0.0, 1.0), 1.0)
    link.reset_feedback()
    assert math.isnan(link.pos_rad) and math.isnan(link.vel_rad_s)
    assert (link.encoder_t_s, link.heartbeat_t_s, link.bus_voltage_t_s, link.temperature_t_s, link.iq_t_s) == (
        -math.inf,) * 5
    assert (link.state, link.error, link.procedure_result) == (AxisState.UNDEFINED, 0, 0)
    assert (link.bus_voltage_v, link.fet_temp_c, link.motor_temp_c, link.iq_a) == (None,) * 4
    assert type(link.error) is int and link.state is AxisState.UNDEFINED


def test_the_velocity_feed_forward_saturates_at_the_signal_s_32_rev_s_exactly():
    link = hip()  # 1 rad/s = 6/(2 pi) rev/s
    k = 6.0 / (2 * math.pi)
    for qd, expected in ((32.0 / k, 32.0), (-32.0 / k, -32.0), (31.5 / k, 31.5), (-31.5 / k, -31.5), (0.0, 0.0)):
        assert POS.unpack(link.pos_frame(0.0, qd).data)[1] == pytest.approx(expected, abs=1e-3), qd


# --------------------------------------------------------------------------- exact bounds (a gear of 2 pi: 1 rev = 1 rad)
def exact(min_rad=-1.0, max_rad=1.0, offset=0.0, limits=FeedbackLimits()) -> AxisLink:
    """An axis whose joint angle [rad] is exactly its motor position [rev] minus ``offset``."""
    cfg = AxisConfig("hip", node_id=0, min_rad=min_rad, max_rad=max_rad, gear_ratio=2 * math.pi,
                     zero_offset_rev=offset)
    link = AxisLink(cfg, C, limits)
    assert link._rad_per_rev == 1.0  # the premise: the conversions below are exact
    return link


def test_a_reading_exactly_at_the_position_slack_is_accepted_and_the_offset_is_subtracted():
    limits = FeedbackLimits(pos_slack_rad=0.5)
    for rev, ok in ((1.5, True), (-1.5, True), (float(np.nextafter(1.5, 2.0)), False),
                    (float(np.nextafter(-1.5, -2.0)), False)):
        link = exact(limits=limits)  # [-1, 1] rad -> readings in [-1.5, 1.5] rad
        assert link.on_encoder((rev, 0.0), 0.0) is ok, rev
    link = exact(offset=1.0, limits=limits)
    assert link.on_encoder((1.75, 0.0), 0.0) and link.pos_rad == 0.75


def test_a_jump_exactly_at_the_bound_is_believed():
    limits = FeedbackLimits(pos_slack_rad=10.0, max_joint_speed_rad_s=10.0, min_jump_dt_s=0.25, jump_slack_rad=0.5)
    link = exact(min_rad=-6.0, max_rad=6.0, limits=limits)
    assert link.on_encoder((0.0, 0.0), 1.0)
    assert link.on_encoder((3.0, 0.0), 1.25)  # 10 rad/s x 0.25 s + 0.5 rad = 3.0 rad: the bound itself
    assert not link.on_encoder((6.0 + 1e-9, 0.0), 1.5) and link.pos_rad == 3.0


def test_targets_exactly_at_the_limits_are_sent_unchanged_and_not_counted():
    link = exact()
    for q in (-1.0, 1.0):
        assert sent_rad(link, link.pos_frame(q)) == q
    assert link.clamped_targets == 0


def test_a_range_holding_a_single_float32_bounds_the_targets_to_it():
    from controller.io.axis import float32_target_bounds_rev

    cfg = AxisConfig("hip", node_id=0, min_rad=1.0, max_rad=1.0 + 2.0 ** -30, gear_ratio=2 * math.pi)
    assert float32_target_bounds_rev(cfg) == (1.0, 1.0)  # float32 steps at 1 are 2**-23
    link = AxisLink(cfg, C)
    assert sent_rad(link, link.pos_frame(5.0)) == 1.0


def test_the_outermost_float32_when_a_limit_is_itself_a_float32():
    from controller.io.axis import float32_target_bounds_rev

    cfg = AxisConfig("hip", node_id=0, min_rad=-1.0, max_rad=0.5, gear_ratio=2 * math.pi)
    assert float32_target_bounds_rev(cfg) == (-1.0, 0.5)
    offset = AxisConfig("hip", node_id=0, min_rad=-1.0, max_rad=0.5, gear_ratio=2 * math.pi, zero_offset_rev=0.25)
    assert float32_target_bounds_rev(offset) == (-0.75, 0.75)


def test_the_feed_forward_is_zero_unless_given_and_saturates_between_32_and_the_signal_s_range():
    link = exact(min_rad=-6.0, max_rad=6.0)  # 1 rad/s = 1 rev/s
    assert POS.unpack(link.pos_frame(0.5).data)[1] == 0.0
    for qd, expected in ((32.5, 32.0), (-32.5, -32.0), (32.0, 32.0), (-31.0, -31.0)):
        assert POS.unpack(link.pos_frame(0.5, qd).data)[1] == pytest.approx(expected, abs=1e-3), qd


def test_an_sdo_write_of_a_float_beyond_float32_is_a_value_error_naming_it():
    from protocol.endpoints import WATCHDOG_TIMEOUT

    with pytest.raises(ValueError, match="does not fit a float32 SDO value"):
        hip().sdo_write_frame(WATCHDOG_TIMEOUT, 1e39)


# --------------------------------------------------------------------------- the payload's fast path
def _reference_pos_payload(link: AxisLink, q_rad: float, qd_rad_s: float) -> bytes:
    """Set_Input_Pos's payload as pos_frame built it before its fast path: the codec packs it all."""
    q = link.clamp(q_rad)
    link.last_target_rad = q
    rev_per_rad = link.config.direction * link.config.gear_ratio / (2.0 * math.pi)
    vel_ff = qd_rad_s * rev_per_rad if math.isfinite(qd_rad_s) else 0.0
    vel_ff = 32.0 if vel_ff > 32.0 else (-32.0 if vel_ff < -32.0 else vel_ff)
    rev = link.config.zero_offset_rev + q * rev_per_rad
    lo, hi = link.pos_bounds_rev
    rev = lo if rev < lo else (hi if rev > hi else rev)
    return POS.pack(rev, vel_ff, 0.0)


@pytest.mark.parametrize("cfg", [
    *default_axes(),
    AxisConfig("hip", node_id=0, min_rad=0.1, max_rad=0.3, gear_ratio=9.0, zero_offset_rev=-17.3),
    AxisConfig("knee", node_id=1, min_rad=-6.0, max_rad=6.0, gear_ratio=101.0, direction=-1, zero_offset_rev=999.0),
], ids=["hip", "knee", "offset", "reversed"])
def test_pos_frame_sends_the_bytes_the_codec_packs(cfg):
    """pos_frame packs a frame without feed-forward as float32 + a fixed tail: byte for byte what
    the codec packs, for targets inside, outside and at the limits, NaN, and with feed-forward."""
    fast, ref = AxisLink(cfg, C), AxisLink(cfg, C)
    assert fast._pos_tail_still is not None  # the DBC's layout takes the fast path
    rng = np.random.default_rng(7)
    span = cfg.max_rad - cfg.min_rad
    targets = [*rng.uniform(cfg.min_rad - span, cfg.max_rad + span, 3000), cfg.min_rad, cfg.max_rad, 0.0, -0.0,
               math.nan, math.inf, -math.inf, math.nextafter(cfg.max_rad, math.inf)]
    for q in targets:
        for qd in (0.0, -0.0, 0.3, -1e9, math.nan):
            frame = fast.pos_frame(q, qd)
            assert bytes(frame.data) == _reference_pos_payload(ref, q, qd), (q, qd)
            assert frame.arbitration_id == fast.pos_id and frame.dlc == POS.dlc
            assert fast.last_target_rad == ref.last_target_rad
    assert fast.clamped_targets == ref.clamped_targets > 0
