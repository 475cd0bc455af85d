"""One ODrive axis as the controller sees it: its feedback and the frames that command it.

Feedback arrives from Heartbeat and Get_Encoder_Estimates frames and is converted to joint
units through the axis's gear ratio, direction and zero offset. A feedback frame is applied
whole or not at all: the handlers return False (the frame is counted ``invalid`` and dropped by
:class:`controller.io.bus.BusIO`) for a heartbeat whose Axis_State is not an ODrive state, whose
Axis_Error has bits firmware 0.6 does not define, and for encoder estimates that are NaN, infinite, faster than
``FeedbackLimits.max_vel_rev_s``, further than ``FeedbackLimits.pos_slack_rad`` outside the
joint's range, or that jump from the last accepted reading faster than
``FeedbackLimits.max_joint_speed_rad_s`` (no joint of the rig can do that: a corrupted frame).
A heartbeat that reports an error is applied whatever the state (in closed loop too): the
supervisor acts on it in that tick. The drivers' health readings (Get_Bus_Voltage_Current,
Get_Temperature, Get_Iq, sent cyclically: :mod:`controller.io.health`) are kept as they come.

Every position command passes through :meth:`AxisLink.pos_frame`, which clamps the target into
``[min_rad, max_rad]`` (a NaN or infinite target holds the last target, or before any the measured
position, or 0; never a limit) and then clamps the motor position it
encodes into ``pos_bounds_rev``: the float32 values whose joint angle, converted back with the
axis's :class:`AxisConfig`, lies inside ``[min_rad, max_rad]``. Rounding to
the frame's float32 can therefore never carry a target past a limit: no code path can put a
joint target outside the configured limits on the bus (``BusIO.send`` checks it again).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Final

import can

from controller.settings.schema import REQUIRED, check_settings, setting
from protocol import SENSOR_BOARD_NODE_ID, AxisError, AxisState, BusContract, ControlMode, InputMode, data_frame
from protocol.contract import sdo_bits_value, sdo_value_bits
from protocol.endpoints import BY_ID as ENDPOINTS_BY_ID
from protocol.endpoints import SDO_OPCODE_READ, SDO_OPCODE_WRITE, Endpoint
from protocol.compiled import interpreted

# (Final: C globals when compiled, not a module-dict lookup per use)
_F32: Final = struct.Struct("<f")
_U32: Final = struct.Struct("<I")
_F32_MAX: Final = 3.4028234663852886e38
# Bound once: a member read through its enum class goes through the metaclass's attribute hook
# (about 1,000 instructions), and closed_loop reads this one every tick.
_CLOSED_LOOP: Final = AxisState.CLOSED_LOOP_CONTROL


_KNOWN_ERRORS = int(sum(e.value for e in AxisError))  # every Axis_Error bit firmware 0.6 defines


TWO_PI: Final = 2.0 * math.pi

MAX_BUS_VOLTAGE_V: Final = 100.0
"""A Get_Bus_Voltage_Current reading above this is a corrupted frame (ODrive S1/Pro: 12-48 V)."""


def plausible_temperature(value: float) -> bool:
    """A thermistor reading a frame may carry: -60..300 C (NaN, "no thermistor", is handled apart).
    (Frame validation, so here; the thresholds that stop the leg are :mod:`controller.io.health`'s.)"""
    return -60.0 <= value <= 300.0 and math.isfinite(value)


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class AxisConfig:
    """One joint driven by one ODrive axis (``name``: "hip" or "knee"). Each other field's unit,
    range and meaning are declared with it below.

    ``current_limit_a`` is ODrive's ``motor.config.current_lim`` at run time: it bounds the torque
    to Kt times it. Its default is the simulated drivers' hardware limit (a lower value lowers their
    torque clamp, a higher one is capped by the hardware). ``vel_limit_rev_s`` is ODrive's
    ``controller.config.vel_limit`` (motor side); its default is the simulated drivers' own. Keep
    it well below ``FeedbackLimits.max_vel_rev_s``: faster encoder readings are taken for
    corrupted frames.
    """

    name: str
    node_id: int = setting(REQUIRED, "(CAN node id)", 0, 63,
                           "the axis's CANSimple node id (ODrive axis.config.can.node_id)",
                           exclude=((SENSOR_BOARD_NODE_ID, "that is the sensor board's"),))
    min_rad: float = setting(REQUIRED, "rad", -TWO_PI, TWO_PI, "lowest joint angle ever commanded")
    max_rad: float = setting(REQUIRED, "rad", -TWO_PI, TWO_PI, "highest joint angle ever commanded")
    gear_ratio: float = setting(6.0, "rev/rev", 0.1, 1000.0, "motor revolutions per joint revolution")
    direction: int = setting(1, doc="the sign from joint angle to motor angle", choices=(1, -1))
    zero_offset_rev: float = setting(0.0, "rev", -1000.0, 1000.0, "motor position at joint angle 0 (calibration)")
    current_limit_a: float = setting(20.0, "A", 0.1, 200.0, "motor current limit, sent with Set_Limits at arming")
    vel_limit_rev_s: float = setting(20.0, "rev/s", 0.1, 80.0, "motor velocity limit, sent with Set_Limits at arming")

    def __post_init__(self) -> None:
        check_settings(self, f"axes.{self.name}")
        if not self.min_rad < self.max_rad:
            raise ValueError(f"axes.{self.name}: min_rad {self.min_rad} must be below max_rad {self.max_rad}")

    def rad_to_rev(self, q_rad: float) -> float:
        return self.zero_offset_rev + self.direction * self.gear_ratio * q_rad / (2.0 * math.pi)

    def rev_to_rad(self, pos_rev: float) -> float:
        return (pos_rev - self.zero_offset_rev) * 2.0 * math.pi / (self.direction * self.gear_ratio)

    def rad_s_to_rev_s(self, qd_rad_s: float) -> float:
        return self.direction * self.gear_ratio * qd_rad_s / (2.0 * math.pi)

    def rev_s_to_rad_s(self, vel_rev_s: float) -> float:
        return vel_rev_s * 2.0 * math.pi / (self.direction * self.gear_ratio)


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class FeedbackLimits:
    """What a plausible encoder reading is (anything else is a corrupted frame, dropped).

    Attributes:
        max_vel_rev_s: largest believable abs(Vel_Estimate) [rev/s, motor side]; default 100.0
            (a KV 100 motor on 24 V turns at most about 40 rev/s unloaded; the drivers limit
            the velocity setpoint to 20 rev/s).
        pos_slack_rad: how far outside ``[min_rad, max_rad]`` a reading may lie [rad, joint
            side]; default 0.5 (the rig's hard stops are 0.05 rad outside the controller's
            limits; the drivers trip 0.02 rev, 0.02 rad, beyond them).
        max_joint_speed_rad_s: a reading further from the last accepted one than this speed
            times the time between them (at least ``min_jump_dt_s``) plus ``jump_slack_rad``
            is a jump no joint makes [rad/s]; default 40 (well above the fastest joint speed
            while stepping over obstacles).
        min_jump_dt_s: the shortest time the jump bound assumes between two readings [s];
            default 0.004 (two encoder periods: frames read in one tick share its clock).
        jump_slack_rad: added to the jump bound [rad]; default 0.05.
    """

    max_vel_rev_s: float = 100.0
    pos_slack_rad: float = 0.5
    max_joint_speed_rad_s: float = 40.0
    min_jump_dt_s: float = 0.004
    jump_slack_rad: float = 0.05

    def __post_init__(self) -> None:
        for name in ("max_vel_rev_s", "pos_slack_rad", "max_joint_speed_rad_s", "min_jump_dt_s", "jump_slack_rad"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"FeedbackLimits.{name} must be finite and > 0, got {value!r}")


def _input_pos_tail_still(codec) -> bytes | None:
    """Set_Input_Pos's payload after Input_Pos when Vel_FF and Torque_FF are 0: bytes 4-7 of
    ``codec.pack(pos, 0.0, 0.0)`` for any ``pos``, so that payload is ``float32(pos) + tail``, where
    the DBC puts Input_Pos as an unscaled little-endian float32 in bytes 0-3 and every other signal
    after it (ODrive's layout); None otherwise (the codec packs every frame)."""
    sig = next(s for s in codec.message.signals if s.name == "Input_Pos")
    others = [s for s in codec.message.signals if s is not sig]
    if not (sig.is_float and sig.length == 32 and sig.start == 0 and sig.byte_order == "little_endian"
            and sig.scale == 1 and sig.offset == 0 and codec.dlc == 8 and codec.signal_names[0] == "Input_Pos"
            and all(s.start >= 32 for s in others)):
        return None
    payload = codec.pack(0.0, 0.0, 0.0)
    if payload[:4] != _F32.pack(0.0) or codec.pack(1.5, 0.0, 0.0) != _F32.pack(1.5) + payload[4:]:
        return None
    return payload[4:]


def _f32(x: float) -> float:
    """``x`` rounded to the nearest float32 (saturated at the float32 range)."""
    return _F32.unpack(_F32.pack(min(_F32_MAX, max(-_F32_MAX, x))))[0]


def _f32_step(x: float, up: bool) -> float:
    """The next float32 above (``up``) or below ``x`` (itself a finite float32)."""
    if x == 0.0:
        tiny = _F32.unpack(_U32.pack(1))[0]
        return tiny if up else -tiny
    bits = _U32.unpack(_F32.pack(x))[0]
    bits += 1 if (x > 0.0) == up else -1
    return _F32.unpack(_U32.pack(bits))[0]


def float32_target_bounds_rev(config: AxisConfig) -> tuple[float, float]:
    """The smallest and largest float32 motor positions [rev] whose joint angle, as
    ``config.rev_to_rad`` computes it, lies in ``[config.min_rad, config.max_rad]``."""
    a, b = config.rad_to_rev(config.min_rad), config.rad_to_rev(config.max_rad)
    lo, hi = _f32(min(a, b)), _f32(max(a, b))

    def inside(rev: float) -> bool:
        return config.min_rad <= config.rev_to_rad(rev) <= config.max_rad

    for _ in range(64):  # rounding to float32 moves a bound by half a step: a few steps at most
        if inside(lo) or lo > hi:
            break
        lo = _f32_step(lo, up=True)
    for _ in range(64):
        if inside(hi) or hi < lo:
            break
        hi = _f32_step(hi, up=False)
    if not (lo <= hi and inside(lo) and inside(hi)):
        raise ValueError(f"axes.{config.name}: the range [{config.min_rad}, {config.max_rad}] rad holds no "
                         "float32 motor position")
    return lo, hi


class AxisLink:
    def __init__(self, config: AxisConfig, contract: BusContract,
                 feedback_limits: FeedbackLimits = FeedbackLimits()) -> None:
        self.config = config
        self.feedback_limits = feedback_limits
        self.name = config.name
        node = config.node_id
        self._pos = contract.codec("Set_Input_Pos")
        self._state = contract.codec("Set_Axis_State")
        self._mode = contract.codec("Set_Controller_Mode")
        self._clear = contract.codec("Clear_Errors")
        self._estop = contract.codec("Estop")
        self._limits = contract.codec("Set_Limits")
        self.pos_id = contract.odrive_id(node, "Set_Input_Pos")
        self.state_id = contract.odrive_id(node, "Set_Axis_State")
        self.mode_id = contract.odrive_id(node, "Set_Controller_Mode")
        self.clear_id = contract.odrive_id(node, "Clear_Errors")
        self.estop_id = contract.odrive_id(node, "Estop")
        self.limits_id = contract.odrive_id(node, "Set_Limits")
        self.heartbeat_id = contract.odrive_id(node, "Heartbeat")
        self.encoder_id = contract.odrive_id(node, "Get_Encoder_Estimates")
        self._init_sdo(contract)
        # joint <-> motor unit factors, precomputed for the 500 Hz path
        self._rev_per_rad = config.direction * config.gear_ratio / (2.0 * math.pi)
        self._rad_per_rev = 1.0 / self._rev_per_rad
        self._offset_rev = config.zero_offset_rev
        self.pos_bounds_rev = float32_target_bounds_rev(config)
        self._vel_max_rev_s = feedback_limits.max_vel_rev_s
        self._pos_lo_rad = config.min_rad - feedback_limits.pos_slack_rad
        self._pos_hi_rad = config.max_rad + feedback_limits.pos_slack_rad
        # the 500 Hz paths read these plain attributes (the config and the limits are frozen)
        self._max_speed_rad_s = feedback_limits.max_joint_speed_rad_s
        self._min_jump_dt_s = feedback_limits.min_jump_dt_s
        self._jump_slack_rad = feedback_limits.jump_slack_rad
        self._pos_lo_rev, self._pos_hi_rev = self.pos_bounds_rev
        self._min_rad: float = config.min_rad
        self._max_rad: float = config.max_rad
        self._pos_tail_still = _input_pos_tail_still(self._pos)
        self.reset_feedback()
        self.clamped_targets = 0
        self.last_target_rad = math.nan

    def reset_feedback(self) -> None:
        self.pos_rad = math.nan
        self.vel_rad_s = math.nan
        self.encoder_t_s = -math.inf
        self.state = AxisState.UNDEFINED
        self.error = 0
        self.procedure_result = 0
        self.heartbeat_t_s = -math.inf
        self.bus_voltage_v: float | None = None
        self.bus_voltage_t_s = -math.inf
        # health readings (controller.io.health): None until received (a NaN thermistor stays None)
        self.fet_temp_c: float | None = None
        self.motor_temp_c: float | None = None
        self.temperature_t_s = -math.inf
        self.iq_a: float | None = None
        self.iq_t_s = -math.inf

    # -- feedback ------------------------------------------------------------------------
    def on_heartbeat(self, values: tuple, now_s: float) -> bool:
        """Heartbeat: False (nothing applied) when Axis_State is not an ODrive axis state or
        Axis_Error has bits firmware 0.6 does not define. An error is applied in any state (in
        closed loop too, where the supervisor makes it a FAULT in the same tick)."""
        error, state, result, _done = values
        try:
            state = AxisState(int(state))
        except ValueError:
            return False
        error = int(error)
        if error & ~_KNOWN_ERRORS:  # bits ODrive 0.6 does not define: a corrupted heartbeat
            return False
        self.error = error
        self.state = state
        self.procedure_result = int(result)
        self.heartbeat_t_s = now_s
        return True

    def on_encoder(self, values: tuple, now_s: float) -> bool:
        """Get_Encoder_Estimates: False (nothing applied) for an implausible reading (NaN,
        infinite, too fast, or too far outside the joint's range; see :class:`FeedbackLimits`)."""
        pos_rev: float  # (declared: compiled, the arithmetic below is on C doubles, not boxed objects)
        vel_rev_s: float
        pos_rev, vel_rev_s = values
        vmax = self._vel_max_rev_s
        if not -vmax <= vel_rev_s <= vmax:  # False for NaN too
            return False
        pos_rad = (pos_rev - self._offset_rev) * self._rad_per_rev
        if not self._pos_lo_rad <= pos_rad <= self._pos_hi_rad:
            return False
        last_s = self.encoder_t_s
        if last_s != -math.inf and abs(pos_rad - self.pos_rad) > (
                self._max_speed_rad_s * max(now_s - last_s, self._min_jump_dt_s) + self._jump_slack_rad):
            return False  # a jump no joint makes: a corrupted reading (bound: see FeedbackLimits)
        self.pos_rad = pos_rad
        self.vel_rad_s = vel_rev_s * self._rad_per_rev
        self.encoder_t_s = now_s
        return True

    def on_bus_voltage(self, values: tuple, now_s: float) -> bool:
        """Get_Bus_Voltage_Current (an answer to a request, or cyclic where the ODrive is set to send
        it): False (nothing applied) for a voltage that is not finite or outside 0-100 V."""
        voltage, current = values
        if not (0.0 <= voltage <= MAX_BUS_VOLTAGE_V and math.isfinite(current)):  # False for NaN too
            return False
        self.bus_voltage_v = float(voltage)
        self.bus_voltage_t_s = now_s
        return True

    def on_temperature(self, values: tuple, now_s: float) -> bool:
        """Get_Temperature (FET, motor) [C]: False (nothing applied) for a value outside -60..300 C
        or infinite; NaN (no thermistor) is kept as None."""
        fet, motor = values
        for t in (fet, motor):
            if t == t and not plausible_temperature(t):
                return False
        self.fet_temp_c = float(fet) if fet == fet else None
        self.motor_temp_c = float(motor) if motor == motor else None
        self.temperature_t_s = now_s
        return True

    def on_iq(self, values: tuple, now_s: float) -> bool:
        """Get_Iq (setpoint, measured) [A]: False (nothing applied) unless the measured Iq is finite."""
        _setpoint, measured = values
        if not math.isfinite(measured):
            return False
        self.iq_a = float(measured)
        self.iq_t_s = now_s
        return True

    @property
    def closed_loop(self) -> bool:
        return self.state == _CLOSED_LOOP and self.error == 0

    # -- commands ------------------------------------------------------------------------
    def clamp(self, q_rad: float) -> float:
        """``q_rad`` [rad] inside ``[min_rad, max_rad]``: a finite target outside goes to the nearest
        limit; a NaN or infinite one holds the last target (before any: the measured position, or
        0), clamped too. Each changed target is counted in ``clamped_targets``."""
        lo, hi = self._min_rad, self._max_rad  # the config's min_rad, max_rad
        if lo <= q_rad <= hi:
            return q_rad
        if not math.isfinite(q_rad):
            # a NaN target is never sent: hold the last target (or the measured position)
            self.clamped_targets += 1
            fallback = self.last_target_rad if math.isfinite(self.last_target_rad) else self.pos_rad
            return min(hi, max(lo, fallback if math.isfinite(fallback) else 0.0))
        if q_rad < lo or q_rad > hi:
            self.clamped_targets += 1
            return lo if q_rad < lo else hi
        return q_rad

    def pos_frame(self, q_rad: float, qd_rad_s: float = 0.0) -> can.Message:
        """Set_Input_Pos for joint target ``q_rad`` [rad] (clamped, see :meth:`clamp`) with
        velocity feed-forward ``qd_rad_s`` [rad/s] (0 if not finite, clamped to the signal's
        +-32 rev/s). The encoded position always lies in ``pos_bounds_rev``."""
        q = self.clamp(q_rad)
        self.last_target_rad = q
        rev = self._offset_rev + q * self._rev_per_rad
        lo = self._pos_lo_rev
        hi = self._pos_hi_rev
        rev = lo if rev < lo else (hi if rev > hi else rev)
        tail = self._pos_tail_still
        if qd_rad_s == 0.0 and tail is not None:
            # no feed-forward (every target of the loop's): the bytes the codec packs for a Vel_FF
            # of +-0.0, the float32 and a fixed tail (see _input_pos_tail_still)
            return data_frame(self.pos_id, _F32.pack(rev) + tail)
        vel_ff = qd_rad_s * self._rev_per_rad if math.isfinite(qd_rad_s) else 0.0
        vel_ff = 32.0 if vel_ff > 32.0 else (-32.0 if vel_ff < -32.0 else vel_ff)
        return data_frame(self.pos_id, self._pos.pack(rev, vel_ff, 0.0))

    def state_frame(self, state: AxisState) -> can.Message:
        return data_frame(self.state_id, self._state.pack(int(state)))

    def mode_frame(self, control: ControlMode, input_mode: InputMode) -> can.Message:
        data = self._mode.pack(int(control), int(input_mode))
        return data_frame(self.mode_id, data)

    def limits_frame(self) -> can.Message:
        """Set_Limits: the configured velocity limit [rev/s, motor side] and current limit [A]."""
        c = self.config
        return data_frame(self.limits_id, self._limits.pack(c.vel_limit_rev_s, c.current_limit_a))

    def clear_errors_frame(self) -> can.Message:
        return data_frame(self.clear_id, self._clear.pack(0))

    def estop_frame(self) -> can.Message:
        """ODrive's Estop (CANSimple cmd 0x002, no payload): the axis disarms and latches
        ESTOP_REQUESTED until Clear_Errors."""
        return data_frame(self.estop_id, b"")

    # -- SDO (RxSdo / TxSdo): endpoint access, ids from protocol.endpoints (UNVERIFIED) ----------
    def _init_sdo(self, contract: BusContract) -> None:
        node = self.config.node_id
        self._rxsdo = contract.codec("RxSdo")
        self.txsdo_codec = contract.codec("TxSdo")
        self.rxsdo_id = contract.odrive_id(node, "RxSdo")
        self.txsdo_id = contract.odrive_id(node, "TxSdo")
        self.sdo_replies: dict[int, tuple[int, float]] = {}  # endpoint id -> (raw Value, time received)

    def sdo_write_frame(self, endpoint: Endpoint, value: float | int | bool) -> can.Message:
        """RxSdo writing ``value`` to ``endpoint`` (a float endpoint's value as its float32 bits)."""
        raw = sdo_value_bits(value) if endpoint.type == "float" else endpoint.to_raw(value)
        return data_frame(self.rxsdo_id, self._rxsdo.pack(SDO_OPCODE_WRITE, endpoint.id, 0, raw))

    def sdo_read_frame(self, endpoint: Endpoint) -> can.Message:
        """RxSdo reading ``endpoint``: the driver answers with TxSdo (:meth:`on_txsdo`)."""
        return data_frame(self.rxsdo_id, self._rxsdo.pack(SDO_OPCODE_READ, endpoint.id, 0, 0))

    def on_txsdo(self, values: tuple, now_s: float) -> bool:
        """TxSdo: the raw Value of the endpoint read, kept by endpoint id with its time (for
        :meth:`sdo_reply`). False (nothing kept) for an endpoint id outside the table."""
        _reserved0, endpoint_id, _reserved1, raw = values
        endpoint_id = int(endpoint_id)
        if endpoint_id not in ENDPOINTS_BY_ID:
            return False
        self.sdo_replies[endpoint_id] = (int(raw), now_s)
        return True

    def sdo_reply(self, endpoint: Endpoint, since_s: float = -math.inf) -> float | int | bool | None:
        """The value the driver last reported for ``endpoint`` at or after ``since_s``, or None."""
        reply = self.sdo_replies.get(endpoint.id)
        if reply is None or reply[1] < since_s:
            return None
        raw = reply[0]
        return sdo_bits_value(raw) if endpoint.type == "float" else endpoint.from_raw(raw)
