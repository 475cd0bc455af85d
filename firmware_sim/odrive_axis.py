"""A simulated ODrive axis (firmware 0.6 CANSimple behaviour) as a CAN node.

:class:`SimOdriveAxis` receives frames addressed to its node id (:meth:`SimOdriveAxis.handle`),
runs ODrive's position/velocity/torque cascade at physics rate (:meth:`SimOdriveAxis.update`)
through a :class:`~firmware_sim.motor.MotorJoint`, and produces its cyclic frames
(:meth:`SimOdriveAxis.due`). Every layout comes from the DBC via :mod:`protocol`.

Behaviour, and where the simulation simplifies the firmware:

- **States.** Power-on state is IDLE, control mode POSITION_CONTROL, input mode PASSTHROUGH.
  Requesting CLOSED_LOOP_CONTROL succeeds only with no active error; otherwise the axis stays
  IDLE with Procedure_Result DISARMED (3). On entry the position input is set to the current
  position, the velocity and torque inputs to zero and the integrator is reset, so the motor
  does not jump. Requesting CLOSED_LOOP_CONTROL while already in it changes nothing (it only
  feeds the watchdog). Calibration-type states (STARTUP_SEQUENCE, FULL_CALIBRATION_SEQUENCE,
  MOTOR_CALIBRATION, ENCODER_*, LOCKIN_SPIN, HOMING, ...) complete instantly and successfully
  and return to IDLE. UNDEFINED and unknown state numbers are ignored (``stats["unsupported"]``).
- **Modes.** VOLTAGE_CONTROL and unknown control/input mode numbers are ignored
  (``stats["unsupported"]``). Every valid input mode is recorded but behaves as PASSTHROUGH
  (no filters or trajectories), so Trajectory_Done_Flag is always 1. A change of control mode
  while in closed loop re-bases the position input on the current position (no jump).
- **Cascade** (motor side: rev, rev/s, N·m). Position mode:
  ``vel_des = input_vel + pos_gain * (input_pos - pos)``; velocity mode: ``vel_des = input_vel``;
  in both, ``vel_des`` is clamped to ±vel_limit (ODrive's ``enable_vel_limit``) and
  ``torque = input_torque + vel_gain * (vel_des - vel) + integrator``. Torque mode:
  ``torque = input_torque``, reduced near the velocity limit as ODrive's
  ``enable_torque_mode_vel_limit`` does, integrator held at zero. The torque is clamped to
  ±Kt·min(current limit, motor hardware limit); while clamped the integrator decays by 1 % a
  step (ODrive's anti-windup), otherwise it integrates ``vel_integrator_gain * v_err * dt``.
- **Inputs.** As in ODrive, Set_Input_Pos writes input_pos, input_vel (Vel_FF) and input_torque
  (Torque_FF); Set_Input_Vel writes input_vel and input_torque; Set_Input_Torque writes
  input_torque. Non-finite values reject the whole frame (``stats["malformed"]``). A position
  target outside [pos_min_rev, pos_max_rev] is accepted and counted in
  ``stats["targets_outside_limits"]``.
- **Errors.** Estop latches ESTOP_REQUESTED and disarms (in any state, IDLE included); the
  watchdog latches WATCHDOG_TIMER_EXPIRED and disarms; a joint pushed past its limit latches
  POSITION_LIMIT_VIOLATION and disarms. Each stays active (refusing closed loop: the axis stays
  IDLE with Procedure_Result DISARMED) until Clear_Errors, which also clears Disarm_Reason and
  the Procedure_Result; Set_Axis_State(IDLE) and calibration requests do not clear them, a
  reboot does (power-on state). Heartbeat.Axis_Error reports ``active_errors | disarm_reason``
  as firmware 0.6 does. ``stats["estops"]``, ``stats["watchdog_trips"]``,
  ``stats["position_limit_trips"]`` and ``stats["missing_estimate_trips"]`` count the events
  (an Estop while already latched counts too; a trip happens only in closed loop).
- **Watchdog.** With ``watchdog_timeout_s > 0`` and the axis in CLOSED_LOOP_CONTROL, every
  well-formed non-RTR frame addressed to the node feeds it (malformed frames, RTR requests and
  zero-length Get_* requests do not, nor do other nodes' frames); entering closed loop feeds
  it, so an axis armed after a long idle spell does not trip at once. It is checked in
  :meth:`update` and before each received frame is processed; more than
  ``watchdog_timeout_s`` since the last feed expires it (exactly the timeout does not). It is
  not checked outside closed loop (an idle axis accumulates no error). Firmware 0.5's
  CANSimple feeds the watchdog on every frame addressed to the axis, RTR requests included;
  the simulation is stricter: a master that only polls cannot keep an axis armed.
- **Position limits.** With ``pos_min_rev`` / ``pos_max_rev`` set and the axis in
  CLOSED_LOOP_CONTROL, a position estimate (Set_Absolute_Position offset included) more than
  ``pos_limit_margin_rev`` outside [pos_min_rev, pos_max_rev] disarms the axis with
  POSITION_LIMIT_VIOLATION in :meth:`update`, before any torque is applied that step; a NaN
  estimate (limits or not) disarms it with MISSING_ESTIMATE. The bounds are precomputed: one
  chained comparison per step.
- **Torque and current limits.** The torque clamp is ``Kt * min(current_limit_a, motor
  hardware limit)``: Set_Limits' current limit lowers it, never raises it above the hardware's
  (:attr:`SimOdriveAxis.torque_limit_nm`).
- **Get_* requests.** An RTR frame, or a data frame of length 0 (as firmware 0.6 also accepts),
  with a Get_* id is answered with a data frame of the same id and the DBC's length. An RTR for
  a command id, or a data frame with payload for a Get_* id, is malformed.
- **Reboot.** Action 0 (reboot) restores the power-on state with the saved configuration;
  action 1 (save configuration) saves the current gains and limits, then reboots; action 2
  (erase configuration) restores the :class:`DriverConfig` values, then reboots; action 3
  (enter DFU) is ignored (``stats["unsupported"]``). Statistics survive a reboot. A reboot
  forgets a Set_Absolute_Position offset.
- **Set_Absolute_Position** sets the position estimate to the given value at the current
  shaft position; in closed loop the position input is shifted by the same amount (no jump).
- **Temperatures** are constant (25 °C FET and motor): no thermal model.
- **Malformed / unknown.** A payload shorter than the DBC's length (Clear_Errors may be 0 or 1
  byte, Estop any length, Reboot 0 bytes means action 0), an unknown command id, an extended
  id or an error frame is counted and ignored. :meth:`handle` never raises; an internal failure
  is counted in ``stats["internal_errors"]``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable

import can

from firmware_sim.motor import MotorJoint
from protocol.contract import (
    CMD_ID_MASK,
    MAX_NODE_ID,
    SENSOR_BOARD_NODE_ID,
    BusContract,
    MessageCodec,
    arbitration_id,
)
from protocol.frame import data_frame
from protocol.odrive import AxisError, AxisState, Cmd, ControlMode, InputMode

PROTOCOL_VERSION = 2
"""Get_Version.Protocol_Version reported by firmware 0.6."""

AMBIENT_TEMPERATURE_C = 25.0
_SCHEDULE_EPS_S = 1e-9


class ProcedureResult(enum.IntEnum):
    """Heartbeat.Procedure_Result values used by the simulation (ODrive 0.6 numbering)."""

    SUCCESS = 0
    BUSY = 1
    CANCELLED = 2
    DISARMED = 3


class RebootAction(enum.IntEnum):
    """Reboot.Action values (firmware 0.6)."""

    REBOOT = 0
    SAVE_CONFIGURATION = 1
    ERASE_CONFIGURATION = 2
    ENTER_DFU_MODE = 3


_INSTANT_PROCEDURES = frozenset(
    s for s in AxisState if s not in (AxisState.UNDEFINED, AxisState.IDLE, AxisState.CLOSED_LOOP_CONTROL)
)
_GET_CMDS = (
    Cmd.GET_VERSION,
    Cmd.HEARTBEAT,
    Cmd.GET_ERROR,
    Cmd.GET_ENCODER_ESTIMATES,
    Cmd.GET_IQ,
    Cmd.GET_TEMPERATURE,
    Cmd.GET_BUS_VOLTAGE_CURRENT,
    Cmd.GET_TORQUES,
    Cmd.GET_POWERS,
)
# Commands whose payload may be shorter than the DBC length: minimum accepted length.
_MIN_LEN_OVERRIDE = {Cmd.ESTOP: 0, Cmd.CLEAR_ERRORS: 0, Cmd.REBOOT: 0}

# Enum members used on the per-step hot path, bound once: ``AxisState.CLOSED_LOOP_CONTROL`` is a
# class-attribute lookup through the enum machinery (~0.2 us each on Python 3.11).
_CLOSED_LOOP = AxisState.CLOSED_LOOP_CONTROL
_TORQUE_CONTROL = ControlMode.TORQUE_CONTROL
_POSITION_CONTROL = ControlMode.POSITION_CONTROL


def _finite(*values: float) -> bool:
    for v in values:
        if not math.isfinite(v):
            return False
    return True


@dataclass(frozen=True)
class DriverConfig:
    """Configuration of one simulated ODrive axis (motor-side units).

    ==========================  =============  ================  ======================================
    Field                       Unit           Default           Meaning
    ==========================  =============  ================  ======================================
    ``node_id``                 –              (required)        CANSimple node id, 0..63, not
                                                                 the sensor board's
    ``pos_gain``                (rev/s)/rev    ``30.0``          position loop proportional gain
    ``vel_gain``                N·m/(rev/s)    ``0.25``          velocity loop proportional gain
    ``vel_integrator_gain``     N·m/rev        ``0.3``           velocity loop integral gain
    ``vel_limit_rev_s``         rev/s          ``20.0``          velocity setpoint clamp
    ``heartbeat_period_s``      s              ``0.1``           Heartbeat period; 0 disables
    ``encoder_period_s``        s              ``0.002``         Get_Encoder_Estimates period;
                                                                 0 disables
    ``watchdog_timeout_s``      s              ``0.1``           command watchdog; 0 disables
    ``pos_min_rev``             rev            ``None``          lower joint limit, motor side; None:
                                                                 unbounded
    ``pos_max_rev``             rev            ``None``          upper joint limit, motor side; None:
                                                                 unbounded
    ``pos_limit_margin_rev``    rev            ``0.02``          in closed loop, a position estimate
                                                                 more than this outside
                                                                 [pos_min_rev, pos_max_rev] is a
                                                                 POSITION_LIMIT_VIOLATION (disarm).
                                                                 0.02 rev is 0.021 rad at the joint
                                                                 behind 6:1: well above the overshoot
                                                                 of a rig joint driven into its URDF
                                                                 stop at full torque
    ``fw_version``              –              ``(0, 6, 10)``    (major, minor, revision) in
                                                                 Get_Version
    ``hw_version``              –              ``(3, 6, 56)``    (major, minor, variant) in
                                                                 Get_Version
    ==========================  =============  ================  ======================================
    """

    node_id: int
    pos_gain: float = 30.0
    vel_gain: float = 0.25
    vel_integrator_gain: float = 0.3
    vel_limit_rev_s: float = 20.0
    heartbeat_period_s: float = 0.1
    encoder_period_s: float = 0.002
    watchdog_timeout_s: float = 0.1
    pos_min_rev: float | None = None
    pos_max_rev: float | None = None
    pos_limit_margin_rev: float = 0.02
    fw_version: tuple[int, int, int] = (0, 6, 10)
    hw_version: tuple[int, int, int] = (3, 6, 56)

    def __post_init__(self) -> None:
        if not 0 <= self.node_id <= MAX_NODE_ID or self.node_id == SENSOR_BOARD_NODE_ID:
            raise ValueError(f"node_id must be 0..63 and not {SENSOR_BOARD_NODE_ID}, got {self.node_id}")
        for name in (
            "pos_gain",
            "vel_gain",
            "vel_integrator_gain",
            "vel_limit_rev_s",
            "heartbeat_period_s",
            "encoder_period_s",
            "watchdog_timeout_s",
            "pos_limit_margin_rev",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("pos_min_rev", "pos_max_rev"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"{name} must be finite or None, got {value!r}")
        if self.pos_min_rev is not None and self.pos_max_rev is not None and self.pos_min_rev > self.pos_max_rev:
            raise ValueError("pos_min_rev must not exceed pos_max_rev")
        for name in ("fw_version", "hw_version"):
            value = getattr(self, name)
            if len(value) != 3 or not all(isinstance(v, int) and 0 <= v <= 255 for v in value):
                raise ValueError(f"{name} must be three integers 0..255, got {value!r}")


@dataclass
class _Tunables:
    """What Set_Limits / Set_*_Gain change at run time and what save_configuration keeps."""

    pos_gain: float
    vel_gain: float
    vel_integrator_gain: float
    vel_limit_rev_s: float
    current_limit_a: float


class SimOdriveAxis:
    """One ODrive axis on the bus, driving one :class:`MotorJoint`.

    Public attributes (read them; change them through CAN frames):

    - ``state`` (:class:`AxisState`), ``errors`` (active :class:`AxisError`), ``disarm_reason``,
      ``procedure_result``;
    - ``control_mode``, ``input_mode``, ``input_pos_rev``, ``input_vel_rev_s``, ``input_torque_nm``;
    - ``pos_gain``, ``vel_gain``, ``vel_integrator_gain``, ``vel_limit_rev_s``, ``current_limit_a``;
    - ``torque_setpoint_nm`` (after limiting), ``vel_integrator_nm``;
    - ``stats``: ``{"rx": {name: n}, "tx": {name: n}, "malformed", "unknown", "unsupported",
      "foreign", "internal_errors", "targets_outside_limits", "estops", "watchdog_trips",
      "position_limit_trips", "missing_estimate_trips"}``.
    """

    def __init__(self, config: DriverConfig, motor: MotorJoint, contract: BusContract | None = None) -> None:
        self.config = config
        self.node_id = config.node_id
        self.motor = motor
        contract = contract if contract is not None else BusContract.load()
        self._codecs: dict[int, MessageCodec] = dict(contract.odrive)
        self._arb_ids = {cmd: arbitration_id(self.node_id, cmd) for cmd in self._codecs}
        self._min_len = {cmd: _MIN_LEN_OVERRIDE.get(cmd, codec.dlc) for cmd, codec in self._codecs.items()}
        self._kt = motor.params.torque_constant_nm_per_a
        self._hw_current_limit_a = motor.params.current_limit_a

        self._commands: dict[int, Callable[[bytes | bytearray, float], bool]] = {
            Cmd.ESTOP: self._on_estop,
            Cmd.SET_AXIS_STATE: self._on_set_axis_state,
            Cmd.SET_CONTROLLER_MODE: self._on_set_controller_mode,
            Cmd.SET_INPUT_POS: self._on_set_input_pos,
            Cmd.SET_INPUT_VEL: self._on_set_input_vel,
            Cmd.SET_INPUT_TORQUE: self._on_set_input_torque,
            Cmd.SET_LIMITS: self._on_set_limits,
            Cmd.REBOOT: self._on_reboot,
            Cmd.CLEAR_ERRORS: self._on_clear_errors,
            Cmd.SET_ABSOLUTE_POSITION: self._on_set_absolute_position,
            Cmd.SET_POS_GAIN: self._on_set_pos_gain,
            Cmd.SET_VEL_GAINS: self._on_set_vel_gains,
        }
        self._getters: dict[int, Callable[[], tuple]] = {
            Cmd.GET_VERSION: self._version_values,
            Cmd.HEARTBEAT: self._heartbeat_values,
            Cmd.GET_ERROR: self._error_values,
            Cmd.GET_ENCODER_ESTIMATES: self.encoder_estimates,
            Cmd.GET_IQ: self._iq_values,
            Cmd.GET_TEMPERATURE: self._temperature_values,
            Cmd.GET_BUS_VOLTAGE_CURRENT: self._bus_values,
            Cmd.GET_TORQUES: self._torque_values,
            Cmd.GET_POWERS: self._power_values,
        }
        missing = (set(self._commands) | set(self._getters)) - set(self._codecs)
        if missing:
            raise ValueError(f"the DBC lacks ODrive commands {sorted(missing)}")
        # Get_* requests carry no payload whatever the DBC length of the reply.
        for cmd in self._getters:
            self._min_len[cmd] = 0

        self._hb_codec = self._codecs[Cmd.HEARTBEAT]
        self._enc_codec = self._codecs[Cmd.GET_ENCODER_ESTIMATES]
        self._hb_id = self._arb_ids[Cmd.HEARTBEAT]
        self._enc_id = self._arb_ids[Cmd.GET_ENCODER_ESTIMATES]
        # The config is frozen: its periods and timeout, read on every step, as plain attributes.
        self._hb_period_s = config.heartbeat_period_s
        self._enc_period_s = config.encoder_period_s
        self._watchdog_timeout_s = config.watchdog_timeout_s
        # Position-limit trip bounds (estimate frame, margin included): one comparison per step.
        margin = config.pos_limit_margin_rev
        self._trip_min_rev = -math.inf if config.pos_min_rev is None else config.pos_min_rev - margin
        self._trip_max_rev = math.inf if config.pos_max_rev is None else config.pos_max_rev + margin
        self._unpack_input_pos = self._codecs[Cmd.SET_INPUT_POS].unpack
        self._hb_last_values: tuple | None = None
        self._hb_last_payload = b""

        self.stats: dict = {
            "rx": {codec.name: 0 for codec in self._codecs.values()},
            "tx": {codec.name: 0 for codec in self._codecs.values()},
            "malformed": 0,
            "unknown": 0,
            "unsupported": 0,
            "foreign": 0,
            "internal_errors": 0,
            "targets_outside_limits": 0,
            "estops": 0,
            "watchdog_trips": 0,
            "position_limit_trips": 0,
            "missing_estimate_trips": 0,
        }
        self._rx = self.stats["rx"]
        self._tx = self.stats["tx"]
        self._hb_name = self._hb_codec.name
        self._enc_name = self._enc_codec.name

        self._saved = self._default_tunables()
        self._next_hb = -math.inf
        self._next_enc = -math.inf
        self._power_on()

    # ------------------------------------------------------------------ state
    def _default_tunables(self) -> _Tunables:
        c = self.config
        return _Tunables(c.pos_gain, c.vel_gain, c.vel_integrator_gain, c.vel_limit_rev_s, self._hw_current_limit_a)

    def _power_on(self) -> None:
        s = self._saved
        self.pos_gain = s.pos_gain
        self.vel_gain = s.vel_gain
        self.vel_integrator_gain = s.vel_integrator_gain
        self.vel_limit_rev_s = s.vel_limit_rev_s
        self.current_limit_a = s.current_limit_a
        self.state = AxisState.IDLE
        self.errors = AxisError.NONE
        self.disarm_reason = AxisError.NONE
        self.procedure_result = ProcedureResult.SUCCESS
        self.control_mode = ControlMode.POSITION_CONTROL
        self.input_mode = InputMode.PASSTHROUGH
        self.input_pos_rev = 0.0
        self.input_vel_rev_s = 0.0
        self.input_torque_nm = 0.0
        self.torque_setpoint_nm = 0.0
        self.vel_integrator_nm = 0.0
        self.pos_offset_rev = 0.0
        self._last_feed_s = -math.inf

    def _tunables(self) -> _Tunables:
        return _Tunables(self.pos_gain, self.vel_gain, self.vel_integrator_gain, self.vel_limit_rev_s, self.current_limit_a)

    @property
    def targets_outside_limits(self) -> int:
        return self.stats["targets_outside_limits"]

    @property
    def torque_limit_nm(self) -> float:
        """Rotor torque clamp in force: Kt · min(runtime current limit, hardware limit)."""
        return self._kt * min(self.current_limit_a, self._hw_current_limit_a)

    def encoder_estimates(self) -> tuple[float, float]:
        """``(pos_rev, vel_rev_s)`` as Get_Encoder_Estimates reports them (absolute-position offset included)."""
        pos, vel = self.motor.motor_state()
        return pos + self.pos_offset_rev, vel

    def latch_error(self, error: AxisError) -> None:
        """An error latched before anyone commands the axis (an e-stop pressed, a fault left from an
        earlier run): held as the firmware holds it, the axis IDLE until Clear_Errors."""
        self._disarm(error)

    def _disarm(self, error: AxisError) -> None:
        self.errors |= error
        self.disarm_reason |= error
        if self.state is not AxisState.IDLE:
            self.procedure_result = ProcedureResult.DISARMED
        self.state = AxisState.IDLE
        self.torque_setpoint_nm = 0.0
        self.vel_integrator_nm = 0.0

    def _enter_closed_loop(self, now_s: float) -> None:
        self.state = AxisState.CLOSED_LOOP_CONTROL
        self.procedure_result = ProcedureResult.SUCCESS
        self.input_pos_rev = self.encoder_estimates()[0]
        self.input_vel_rev_s = 0.0
        self.input_torque_nm = 0.0
        self.vel_integrator_nm = 0.0
        self._last_feed_s = now_s

    def _check_watchdog(self, now_s: float) -> None:
        timeout = self._watchdog_timeout_s
        if timeout > 0.0 and self.state is _CLOSED_LOOP and now_s - self._last_feed_s > timeout:
            self.stats["watchdog_trips"] += 1
            self._disarm(AxisError.WATCHDOG_TIMER_EXPIRED)

    # ------------------------------------------------------------------ receive
    def handle(self, msg: can.Message, now_s: float) -> list[can.Message]:
        """Process one frame addressed to this node; returns the reply frames (maybe none). Never raises."""
        try:
            return self._handle(msg, now_s)
        except Exception:  # noqa: BLE001 - a simulated node must never bring the bus down
            self.stats["internal_errors"] += 1
            return []

    def _handle(self, msg: can.Message, now_s: float) -> list[can.Message]:
        if msg.is_extended_id or msg.is_error_frame:
            self.stats["unknown"] += 1
            return []
        arb = msg.arbitration_id
        if arb >> 5 != self.node_id:
            self.stats["foreign"] += 1
            return []
        cmd = arb & CMD_ID_MASK
        codec = self._codecs.get(cmd)
        if codec is None:
            self.stats["unknown"] += 1
            return []
        self._rx[codec.name] += 1
        getter = self._getters.get(cmd)
        data = msg.data
        if getter is not None:
            if msg.is_remote_frame or not data:
                return [self._frame(cmd, codec, getter())]
            self.stats["malformed"] += 1
            return []
        if msg.is_remote_frame:
            self.stats["malformed"] += 1
            return []
        handler = self._commands.get(cmd)
        if handler is None or len(data) < self._min_len[cmd]:
            self.stats["malformed"] += 1
            return []
        self._check_watchdog(now_s)
        if handler(data, now_s):
            self._last_feed_s = now_s
        else:
            self.stats["malformed"] += 1
        return []

    def _frame(self, cmd: int, codec: MessageCodec, values: tuple) -> can.Message:
        self._tx[codec.name] += 1
        return data_frame(self._arb_ids[cmd], codec.pack(*values))

    # Command handlers: return False when the payload is malformed (non-finite, negative limit).
    def _on_estop(self, data, now_s) -> bool:
        self.stats["estops"] += 1
        self._disarm(AxisError.ESTOP_REQUESTED)
        return True

    def _on_set_axis_state(self, data, now_s) -> bool:
        requested = int(self._codecs[Cmd.SET_AXIS_STATE].unpack(data)[0])
        if requested == AxisState.IDLE:
            self.state = AxisState.IDLE
            self.torque_setpoint_nm = 0.0
            self.vel_integrator_nm = 0.0
        elif requested == AxisState.CLOSED_LOOP_CONTROL:
            if self.errors:
                self.state = AxisState.IDLE
                self.procedure_result = ProcedureResult.DISARMED
            elif self.state is not AxisState.CLOSED_LOOP_CONTROL:
                self._enter_closed_loop(now_s)
        elif requested in _INSTANT_PROCEDURES:
            if self.errors:
                self.procedure_result = ProcedureResult.DISARMED
            else:
                self.procedure_result = ProcedureResult.SUCCESS
            self.state = AxisState.IDLE
            self.torque_setpoint_nm = 0.0
            self.vel_integrator_nm = 0.0
        else:
            self.stats["unsupported"] += 1
        return True

    def _on_set_controller_mode(self, data, now_s) -> bool:
        control, inp = (int(v) for v in self._codecs[Cmd.SET_CONTROLLER_MODE].unpack(data))
        if control not in (ControlMode.TORQUE_CONTROL, ControlMode.VELOCITY_CONTROL, ControlMode.POSITION_CONTROL):
            self.stats["unsupported"] += 1
            return True
        try:
            input_mode = InputMode(inp)
        except ValueError:
            self.stats["unsupported"] += 1
            return True
        control_mode = ControlMode(control)
        if control_mode is not self.control_mode and self.state is AxisState.CLOSED_LOOP_CONTROL:
            self.input_pos_rev = self.encoder_estimates()[0]
        self.control_mode = control_mode
        self.input_mode = input_mode
        return True

    def _on_set_input_pos(self, data, now_s) -> bool:
        pos, vel_ff, torque_ff = self._unpack_input_pos(data)
        if not math.isfinite(pos):
            return False
        c = self.config
        if (c.pos_min_rev is not None and pos < c.pos_min_rev) or (c.pos_max_rev is not None and pos > c.pos_max_rev):
            self.stats["targets_outside_limits"] += 1
        self.input_pos_rev = pos
        self.input_vel_rev_s = vel_ff
        self.input_torque_nm = torque_ff
        return True

    def _on_set_input_vel(self, data, now_s) -> bool:
        vel, torque_ff = self._codecs[Cmd.SET_INPUT_VEL].unpack(data)
        if not _finite(vel, torque_ff):
            return False
        self.input_vel_rev_s = vel
        self.input_torque_nm = torque_ff
        return True

    def _on_set_input_torque(self, data, now_s) -> bool:
        (torque,) = self._codecs[Cmd.SET_INPUT_TORQUE].unpack(data)
        if not math.isfinite(torque):
            return False
        self.input_torque_nm = torque
        return True

    def _on_set_limits(self, data, now_s) -> bool:
        vel_limit, current_limit = self._codecs[Cmd.SET_LIMITS].unpack(data)
        if not (_finite(vel_limit, current_limit) and vel_limit >= 0.0 and current_limit >= 0.0):
            return False
        self.vel_limit_rev_s = vel_limit
        self.current_limit_a = current_limit
        return True

    def _on_reboot(self, data, now_s) -> bool:
        action = data[0] if data else RebootAction.REBOOT
        if action == RebootAction.SAVE_CONFIGURATION:
            self._saved = self._tunables()
        elif action == RebootAction.ERASE_CONFIGURATION:
            self._saved = self._default_tunables()
        elif action != RebootAction.REBOOT:
            self.stats["unsupported"] += 1
            return True
        self._power_on()
        return True

    def _on_clear_errors(self, data, now_s) -> bool:
        self.errors = AxisError.NONE
        self.disarm_reason = AxisError.NONE
        self.procedure_result = ProcedureResult.SUCCESS
        return True

    def _on_set_absolute_position(self, data, now_s) -> bool:
        (position,) = self._codecs[Cmd.SET_ABSOLUTE_POSITION].unpack(data)
        if not math.isfinite(position):
            return False
        old = self.encoder_estimates()[0]
        self.pos_offset_rev += position - old
        if self.state is AxisState.CLOSED_LOOP_CONTROL:
            self.input_pos_rev += position - old
        return True

    def _on_set_pos_gain(self, data, now_s) -> bool:
        (gain,) = self._codecs[Cmd.SET_POS_GAIN].unpack(data)
        if not (math.isfinite(gain) and gain >= 0.0):
            return False
        self.pos_gain = gain
        return True

    def _on_set_vel_gains(self, data, now_s) -> bool:
        vel_gain, integrator_gain = self._codecs[Cmd.SET_VEL_GAINS].unpack(data)
        if not (_finite(vel_gain, integrator_gain) and vel_gain >= 0.0 and integrator_gain >= 0.0):
            return False
        self.vel_gain = vel_gain
        self.vel_integrator_gain = integrator_gain
        return True

    # ------------------------------------------------------------------ reply values (DBC signal order)
    def _version_values(self) -> tuple:
        hw, fw = self.config.hw_version, self.config.fw_version
        return (PROTOCOL_VERSION, hw[0], hw[1], hw[2], fw[0], fw[1], fw[2], 0)

    def _heartbeat_values(self) -> tuple:
        return (int(self.errors | self.disarm_reason), int(self.state), int(self.procedure_result), 1)

    def _error_values(self) -> tuple:
        return (int(self.errors), int(self.disarm_reason))

    def _iq_values(self) -> tuple:
        return (self.motor.iq_setpoint_a, self.motor.iq_measured_a)

    def _temperature_values(self) -> tuple:
        return (AMBIENT_TEMPERATURE_C, AMBIENT_TEMPERATURE_C)

    def _bus_values(self) -> tuple:
        return (self.motor.params.bus_voltage_v, self.motor.bus_current_a)

    def _torque_values(self) -> tuple:
        return (self.torque_setpoint_nm, self.motor.torque_estimate_nm)

    def _power_values(self) -> tuple:
        return (self.motor.electrical_power_w, self.motor.mechanical_power_w)

    # ------------------------------------------------------------------ control loop
    def update(self, now_s: float, dt_s: float) -> None:
        """One control step at physics rate: watchdog, position-limit check, the cascade, the motor torque."""
        self._check_watchdog(now_s)
        motor = self.motor
        raw_pos, vel = motor.motor_state()
        if self.state is not _CLOSED_LOOP:
            self.torque_setpoint_nm = 0.0
            self.vel_integrator_nm = 0.0
            motor.apply_motor_torque(0.0, vel)
            return
        pos = raw_pos + self.pos_offset_rev
        if not self._trip_min_rev <= pos <= self._trip_max_rev:  # also true for a NaN estimate
            if pos != pos:
                self.stats["missing_estimate_trips"] += 1
                self._disarm(AxisError.MISSING_ESTIMATE)
            else:
                self.stats["position_limit_trips"] += 1
                self._disarm(AxisError.POSITION_LIMIT_VIOLATION)
            motor.apply_motor_torque(0.0, vel)
            return
        mode = self.control_mode
        vel_limit = self.vel_limit_rev_s
        torque_limit = self.torque_limit_nm
        if mode is _TORQUE_CONTROL:
            torque = self.input_torque_nm
            # ODrive's enable_torque_mode_vel_limit: no torque that pushes further past the limit.
            t_max = (vel_limit - vel) * self.vel_gain
            t_min = (-vel_limit - vel) * self.vel_gain
            if torque > t_max:
                torque = t_max
            elif torque < t_min:
                torque = t_min
            if torque > torque_limit:
                torque = torque_limit
            elif torque < -torque_limit:
                torque = -torque_limit
            self.vel_integrator_nm = 0.0
        else:
            vel_des = self.input_vel_rev_s
            if mode is _POSITION_CONTROL:
                vel_des += self.pos_gain * (self.input_pos_rev - pos)
            if vel_des > vel_limit:
                vel_des = vel_limit
            elif vel_des < -vel_limit:
                vel_des = -vel_limit
            v_err = vel_des - vel
            torque = self.input_torque_nm + self.vel_gain * v_err + self.vel_integrator_nm
            if torque > torque_limit:
                torque = torque_limit
                self.vel_integrator_nm *= 0.99
            elif torque < -torque_limit:
                torque = -torque_limit
                self.vel_integrator_nm *= 0.99
            else:
                self.vel_integrator_nm += self.vel_integrator_gain * dt_s * v_err
        self.torque_setpoint_nm = torque
        motor.apply_motor_torque(torque, vel)

    # ------------------------------------------------------------------ cyclic frames
    def due(self, now_s: float) -> list[can.Message]:
        """Cyclic frames whose period has elapsed: Heartbeat and Get_Encoder_Estimates.

        The first call sends both; then each is scheduled drift-free (``next += period``),
        resynchronised to ``now + period`` when more than a period behind.
        """
        out: list[can.Message] = []
        period = self._hb_period_s
        if period > 0.0 and now_s >= self._next_hb - _SCHEDULE_EPS_S:
            nxt = self._next_hb + period
            self._next_hb = nxt if nxt > now_s else now_s + period
            self._tx[self._hb_name] += 1
            values = self._heartbeat_values()
            # Heartbeat has a 1-bit field, so it packs through cantools (~10 us); its values (all
            # ints) rarely change, so reuse the last payload while they are the same.
            if values != self._hb_last_values:
                self._hb_last_payload = self._hb_codec.pack(*values)
                self._hb_last_values = values
            out.append(data_frame(self._hb_id, self._hb_last_payload))
        period = self._enc_period_s
        if period > 0.0 and now_s >= self._next_enc - _SCHEDULE_EPS_S:
            nxt = self._next_enc + period
            self._next_enc = nxt if nxt > now_s else now_s + period
            self._tx[self._enc_name] += 1
            out.append(data_frame(self._enc_id, self._enc_codec.pack(*self.encoder_estimates())))
        return out
