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
  (``stats["unsupported"]``). Every valid input mode is recorded; all but TRAP_TRAJ behave as
  PASSTHROUGH (no filters). A change of control mode while in closed loop re-bases the position
  input on the current position (no jump).
- **TRAP_TRAJ** (input mode 5, position control, closed loop): each Set_Input_Pos plans ODrive's
  trapezoidal move (:class:`firmware_sim.trajectory.TrapezoidalTrajectory`: accelerate, cruise,
  decelerate) from the setpoint (at rest: the last target or the position held at arming; during
  a move: where the move is now, with its velocity) to the target, with the limits of
  Set_Traj_Vel_Limit and Set_Traj_Accel_Limits (ODrive's defaults 2 rev/s, 0.5 rev/s²) at that
  moment; the move's position and velocity are the cascade's setpoints and its acceleration
  times Set_Traj_Inertia (default 0) the torque feed-forward (Vel_FF and Torque_FF are ignored).
  Heartbeat.Trajectory_Done_Flag is 0 while a move runs and 1 otherwise (always 1 outside
  TRAP_TRAJ). A change of input or control mode, IDLE, a disarm or entering closed loop ends a
  move; the position input stays its target. Limits must be finite and > 0 (inertia >= 0),
  else the frame is malformed.
- **SDO** (RxSdo / TxSdo): the endpoints of :mod:`protocol.endpoints` (ids UNVERIFIED, the gains'
  and input mode's placeholders) served here: axis0.config.watchdog_timeout and enable_watchdog
  (a write changes the timeout the watchdog enforces at once), axis0.controller.config.input_mode,
  pos_gain, vel_gain, vel_integrator_gain (as Set_Controller_Mode / Set_*_Gain would),
  axis0.requested_state (write: as Set_Axis_State), and read-only axis0.current_state,
  pos_estimate, vel_estimate, config.can.node_id (a write is ``stats["unsupported"]``). Opcode 0
  (read) is answered with TxSdo carrying the value (``stats["sdo_reads"]``); opcode 1 (write)
  with nothing (``stats["sdo_writes"]``); another opcode or a value the endpoint refuses is
  malformed. An endpoint not served (the DC-bus trip levels included) is answered with nothing,
  as ODrive does, and counted in ``stats["sdo_unknown_endpoint"]``. The watchdog settings and the
  trajectory limits are configuration: save_configuration keeps them, a reboot restores the saved
  ones.
- **Address** (0x006): an RTR or empty frame to the node is answered with Address carrying the
  node id and the board's 48-bit serial number (``DriverConfig.serial_number``, by default
  :func:`default_serial_number` of the node id: stable per board). The node-id assignment form
  (a payload) is not simulated (malformed), nor the broadcast node id 0x3F (the node host routes
  by node id).
- **Enter_DFU_Mode** is refused: no effect, counted in ``stats["dfu_refused"]``.
- **Set_Axis_State** accepts the DBC's 8 bytes and the 4 ODrive's own example sends (the
  contract's :data:`protocol.contract.SHORT_FRAMES`).
- **Versions**: Get_Version reports an ODrive Pro, hardware 4.4 variant 58, with firmware 0.6.10
  (see :class:`DriverConfig`).
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
- **Health readings.** Get_Temperature and Get_Bus_Voltage_Current come from the axis's
  :class:`~firmware_sim.thermal.ThermalModel` (``thermal``: motor and FET temperatures from the
  applied current, a bus voltage that sags under load), stepped in :meth:`update`; it never acts
  on the physics. With ``health_period_s > 0`` they and Get_Iq are also sent cyclically, as
  ODrive's ``temperature_msg_rate_ms``, ``bus_voltage_msg_rate_ms`` and ``iq_msg_rate_ms`` do.
- **Malformed / unknown.** A payload shorter than the contract allows (its DBC length, less for
  :data:`protocol.contract.SHORT_FRAMES`; Reboot 0 bytes means action 0), an unknown command id, an extended
  id or an error frame is counted and ignored. :meth:`handle` never raises; an internal failure
  is counted in ``stats["internal_errors"]``.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any, Callable, Final

import can

from firmware_sim.motor import MotorJoint
from firmware_sim.thermal import ThermalModel
from firmware_sim.trajectory import TrapezoidalTrajectory
from protocol.contract import (
    CMD_ID_MASK,
    MAX_NODE_ID,
    SENSOR_BOARD_NODE_ID,
    BusContract,
    MessageCodec,
    arbitration_id,
    sdo_bits_value,
    sdo_value_bits,
)
from protocol.endpoints import BY_ID as ENDPOINTS_BY_ID
from protocol.endpoints import SDO_OPCODE_READ, SDO_OPCODE_WRITE, Endpoint
from protocol.frame import data_frame
from protocol.odrive import AxisError, AxisState, Cmd, ControlMode, InputMode, ProcedureResult, RebootAction
from protocol.compiled import interpreted

PROTOCOL_VERSION = 2
"""Get_Version.Protocol_Version reported by firmware 0.6."""

_SCHEDULE_EPS_S: Final = 1e-9


# SENSORLESS_CONTROL (a control state, not a procedure) is not simulated: "unsupported".
_INSTANT_PROCEDURES = frozenset(
    s for s in AxisState if s.name not in ("UNDEFINED", "IDLE", "CLOSED_LOOP_CONTROL", "SENSORLESS_CONTROL")
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
# The shortest payload accepted is the contract's rule (protocol.contract.SHORT_FRAMES:
# Set_Axis_State 4 bytes as ODrive's own example sends it, RxSdo 4-6, Clear_Errors and Reboot 0).

# Messages added with ODrive's 0.6.10 DBC, addressed by name (protocol.odrive.Cmd does not name them).
_RXSDO, _TXSDO, _ADDRESS = "RxSdo", "TxSdo", "Address"
_SET_TRAJ_VEL_LIMIT, _SET_TRAJ_ACCEL_LIMITS = "Set_Traj_Vel_Limit", "Set_Traj_Accel_Limits"
_SET_TRAJ_INERTIA, _ENTER_DFU_MODE = "Set_Traj_Inertia", "Enter_DFU_Mode"

# ODrive's trap_traj.config defaults (firmware 0.6): vel_limit 2 rev/s, accel/decel 0.5 rev/s^2, inertia 0.
TRAJ_VEL_LIMIT_DEFAULT = 2.0
TRAJ_ACCEL_LIMIT_DEFAULT = 0.5
TRAJ_DECEL_LIMIT_DEFAULT = 0.5
TRAJ_INERTIA_DEFAULT = 0.0


def default_serial_number(node_id: int) -> int:
    """A stable 48-bit serial number for the simulated board at ``node_id`` (the same every run)."""
    digest = hashlib.sha256(f"elegant-stepping simulated ODrive, node {node_id}".encode()).digest()
    return int.from_bytes(digest[:6], "little")

# Enum members used on the per-step hot path, bound once: ``AxisState.CLOSED_LOOP_CONTROL`` is a
# class-attribute lookup through the enum machinery (~0.2 us each on Python 3.11). ``Final`` module
# names (here and above) are C globals when compiled, not a module-dict lookup per use.
_CLOSED_LOOP: Final = AxisState.CLOSED_LOOP_CONTROL
_TORQUE_CONTROL: Final = ControlMode.TORQUE_CONTROL
_POSITION_CONTROL: Final = ControlMode.POSITION_CONTROL
_TRAP_TRAJ: Final = InputMode.TRAP_TRAJ


def _finite(*values: float) -> bool:
    for v in values:
        if not math.isfinite(v):
            return False
    return True


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
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
    ``health_period_s``         s              ``0.0``           Get_Temperature, Get_Bus_Voltage_
                                                                 Current and Get_Iq period; 0
                                                                 disables (ODrive's default)
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
    ``hw_version``              –              ``(4, 4, 58)``    (major, minor, variant) in
                                                                 Get_Version: ODrive Pro v4.4-58V
    ``serial_number``           –              ``None``          48-bit serial number in Address;
                                                                 None: :func:`default_serial_number`
                                                                 of the node id (stable per board)
    ==========================  =============  ================  ======================================

    The version pairing is one that exists for firmware 0.6.10: an ODrive Pro, hardware 4.4
    variant 58, as the ``odrive`` PyPI package 0.6.11.post1 describes the board in
    ``odrive/data/odrive-v4.4.json`` (``{"name": "ODrive Pro v4.4-58V", "hw_version": [4, 4, 58]}``),
    running firmware 0.6.10.
    """

    node_id: int
    pos_gain: float = 30.0
    vel_gain: float = 0.25
    vel_integrator_gain: float = 0.3
    vel_limit_rev_s: float = 20.0
    heartbeat_period_s: float = 0.1
    encoder_period_s: float = 0.002
    watchdog_timeout_s: float = 0.1
    health_period_s: float = 0.0
    pos_min_rev: float | None = None
    pos_max_rev: float | None = None
    pos_limit_margin_rev: float = 0.02
    fw_version: tuple[int, int, int] = (0, 6, 10)
    hw_version: tuple[int, int, int] = (4, 4, 58)
    serial_number: int | None = None

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
            "health_period_s",
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
        if self.serial_number is not None and not (
                isinstance(self.serial_number, int) and 0 <= self.serial_number < 1 << 48):
            raise ValueError(f"serial_number must be a 48-bit unsigned integer or None, got {self.serial_number!r}")


@dataclass
class _Tunables:
    """What Set_Limits / Set_*_Gain change at run time and what save_configuration keeps."""

    pos_gain: float
    vel_gain: float
    vel_integrator_gain: float
    vel_limit_rev_s: float
    current_limit_a: float
    watchdog_timeout_s: float = 0.0
    enable_watchdog: bool = False
    traj_vel_limit: float = TRAJ_VEL_LIMIT_DEFAULT
    traj_accel_limit: float = TRAJ_ACCEL_LIMIT_DEFAULT
    traj_decel_limit: float = TRAJ_DECEL_LIMIT_DEFAULT
    traj_inertia: float = TRAJ_INERTIA_DEFAULT


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
      "position_limit_trips", "missing_estimate_trips", "sdo_reads", "sdo_writes", "sdo_unknown_endpoint",
      "dfu_refused"}``;
    - ``watchdog_timeout_s``, ``enable_watchdog`` (SDO), ``traj_vel_limit``, ``traj_accel_limit``,
      ``traj_decel_limit``, ``traj_inertia`` (Set_Traj_*), ``trajectory_done``.
    """

    def __init__(self, config: DriverConfig, motor: MotorJoint, contract: BusContract | None = None) -> None:
        self.config = config
        self.node_id = config.node_id
        self.motor = motor
        contract = contract if contract is not None else BusContract.load()
        self._codecs: dict[int, MessageCodec] = dict(contract.odrive)
        self._arb_ids = {cmd: arbitration_id(self.node_id, cmd) for cmd in self._codecs}
        self._min_len = {cmd: codec.min_length for cmd, codec in self._codecs.items()}
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
        # ODrive 0.6.10's SDO, trajectory and DFU commands, by name (see the module doc).
        for name, handler in ((_RXSDO, self._on_rxsdo), (_SET_TRAJ_VEL_LIMIT, self._on_set_traj_vel_limit),
                              (_SET_TRAJ_ACCEL_LIMITS, self._on_set_traj_accel_limits),
                              (_SET_TRAJ_INERTIA, self._on_set_traj_inertia),
                              (_ENTER_DFU_MODE, self._on_enter_dfu_mode)):
            self._commands[contract.codec(name).cmd_id] = handler
        self._rxsdo_cmd = contract.codec(_RXSDO).cmd_id
        self._traj_vel_cmd = contract.codec(_SET_TRAJ_VEL_LIMIT).cmd_id
        self._traj_accel_cmd = contract.codec(_SET_TRAJ_ACCEL_LIMITS).cmd_id
        self._traj_inertia_cmd = contract.codec(_SET_TRAJ_INERTIA).cmd_id
        self._sdo_reply: can.Message | None = None
        self._sdo_now_s = 0.0
        self._txsdo_codec = contract.codec(_TXSDO)
        self._txsdo_cmd = self._txsdo_codec.cmd_id
        self._sdo_endpoints = self._sdo_table()
        self._serial_number = (config.serial_number if config.serial_number is not None
                               else default_serial_number(config.node_id))
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
            contract.codec(_ADDRESS).cmd_id: self._address_values,
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
        self._pack_enc = self._enc_codec.pack_floats or self._enc_codec.pack
        # The config is frozen: its periods and timeout, read on every step, as plain attributes.
        self._hb_period_s = config.heartbeat_period_s
        self._enc_period_s = config.encoder_period_s
        # The watchdog timeout in force (0: disabled) is set by _power_on and the SDO endpoints.
        # Position-limit trip bounds (estimate frame, margin included): one comparison per step.
        margin = config.pos_limit_margin_rev
        self._trip_min_rev = -math.inf if config.pos_min_rev is None else config.pos_min_rev - margin
        self._trip_max_rev = math.inf if config.pos_max_rev is None else config.pos_max_rev + margin
        # A Set_Input_Pos target outside these is counted (targets_outside_limits); None: unbounded.
        self._target_min_rev = -math.inf if config.pos_min_rev is None else config.pos_min_rev
        self._target_max_rev = math.inf if config.pos_max_rev is None else config.pos_max_rev
        self._unpack_input_pos = self._codecs[Cmd.SET_INPUT_POS].unpack
        self._hb_last_values: tuple | None = None
        self._hb_last_payload = b""

        self.stats: dict[str, Any] = {
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
            "sdo_reads": 0,
            "sdo_writes": 0,
            "sdo_unknown_endpoint": 0,
            "dfu_refused": 0,
        }
        self._rx: dict[str, int] = self.stats["rx"]
        self._tx: dict[str, int] = self.stats["tx"]
        self._hb_name = self._hb_codec.name
        self._enc_name = self._enc_codec.name

        self._saved = self._default_tunables()
        self._next_hb = -math.inf
        self._next_enc = -math.inf
        self.thermal = ThermalModel(motor)  # firmware_sim.leg sets the leg's ThermalParams
        self._health_period_s = config.health_period_s
        self._next_health = -math.inf
        self._power_on()

    # ------------------------------------------------------------------ state
    def _default_tunables(self) -> _Tunables:
        c = self.config
        return _Tunables(c.pos_gain, c.vel_gain, c.vel_integrator_gain, c.vel_limit_rev_s, self._hw_current_limit_a,
                         c.watchdog_timeout_s, c.watchdog_timeout_s > 0.0)

    def _power_on(self) -> None:
        s = self._saved
        self.pos_gain = s.pos_gain
        self.vel_gain = s.vel_gain
        self.vel_integrator_gain = s.vel_integrator_gain
        self.vel_limit_rev_s = s.vel_limit_rev_s
        self.current_limit_a = s.current_limit_a
        self.watchdog_timeout_s = s.watchdog_timeout_s
        self.enable_watchdog = s.enable_watchdog
        self._apply_watchdog()
        self.traj_vel_limit = s.traj_vel_limit
        self.traj_accel_limit = s.traj_accel_limit
        self.traj_decel_limit = s.traj_decel_limit
        self.traj_inertia = s.traj_inertia
        self._traj: TrapezoidalTrajectory | None = None
        self._traj_t0_s = 0.0
        self.trajectory_done = True
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
        return _Tunables(self.pos_gain, self.vel_gain, self.vel_integrator_gain, self.vel_limit_rev_s, self.current_limit_a,
                         self.watchdog_timeout_s, self.enable_watchdog, self.traj_vel_limit, self.traj_accel_limit,
                         self.traj_decel_limit, self.traj_inertia)

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
        self._cancel_trajectory()

    def _enter_closed_loop(self, now_s: float) -> None:
        self._cancel_trajectory()
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

    def _handle(self, msg: Any, now_s: float) -> list[can.Message]:
        # msg: Any, read without mypyc's type checks: a node must survive any frame (a numpy.bool flag too)
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
            if cmd == self._rxsdo_cmd and self._sdo_reply is not None:
                reply, self._sdo_reply = self._sdo_reply, None
                return [reply]
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
        # 4 or 8 bytes: the contract's short-frame rule (protocol.contract.SHORT_FRAMES) zero-pads a short one.
        self._request_state(int(self._codecs[Cmd.SET_AXIS_STATE].unpack(data)[0]), now_s)
        return True

    def _request_state(self, requested: int, now_s: float) -> None:
        """Set_Axis_State, or a write of axis0.requested_state through SDO."""
        if requested == AxisState.IDLE:
            self.state = AxisState.IDLE
            self.torque_setpoint_nm = 0.0
            self.vel_integrator_nm = 0.0
            self._cancel_trajectory()
        elif requested == AxisState.CLOSED_LOOP_CONTROL:
            if self.errors:
                self.state = AxisState.IDLE
                self.procedure_result = ProcedureResult.DISARMED
                self._cancel_trajectory()
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
            self._cancel_trajectory()
        else:
            self.stats["unsupported"] += 1

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
        if control_mode is not self.control_mode:
            self._cancel_trajectory()
            if self.state is AxisState.CLOSED_LOOP_CONTROL:
                self.input_pos_rev = self.encoder_estimates()[0]
        self.control_mode = control_mode
        self._set_input_mode(input_mode)
        return True

    def _on_set_input_pos(self, data, now_s) -> bool:
        pos, vel_ff, torque_ff = self._unpack_input_pos(data)
        if math.isinf(pos) or math.isnan(pos):  # not isfinite: compiled, these two are C calls, it is not
            return False
        if not self._target_min_rev <= pos <= self._target_max_rev:  # (pos is finite here)
            self.stats["targets_outside_limits"] += 1
        if self.input_mode is _TRAP_TRAJ:
            # TRAP_TRAJ: a move from the setpoint to the target; the feed-forwards come from the move.
            if self.state is _CLOSED_LOOP and self.control_mode is _POSITION_CONTROL:
                self._start_trajectory(pos, now_s)
            self.input_pos_rev = pos
            self.input_vel_rev_s = 0.0
            self.input_torque_nm = 0.0
            return True
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

    # ODrive 0.6.10's SDO, trajectory and DFU commands.
    def _apply_watchdog(self) -> None:
        """The timeout the driver enforces: axis0.config.watchdog_timeout if enable_watchdog, else none."""
        self._watchdog_timeout_s = self.watchdog_timeout_s if self.enable_watchdog else 0.0

    def _sdo_table(self) -> dict[int, tuple[Endpoint, Callable[[], float | int | bool],
                                            Callable[[float | int | bool], bool] | None]]:
        """Endpoint id -> (endpoint, getter, setter or None for read-only) of what this driver serves."""
        def set_watchdog_timeout(v):
            if not (math.isfinite(v) and v >= 0.0):
                return False
            self.watchdog_timeout_s = v
            self._apply_watchdog()
            return True

        def set_enable_watchdog(v):
            self.enable_watchdog = bool(v)
            self._apply_watchdog()
            return True

        def set_gain(name):
            def setter(v):
                if not (math.isfinite(v) and v >= 0.0):
                    return False
                setattr(self, name, v)
                return True
            return setter

        def set_input_mode(v):
            try:
                mode = InputMode(int(v))
            except ValueError:
                return False
            self._set_input_mode(mode)
            return True

        def set_requested_state(v):
            self._request_state(int(v), self._sdo_now_s)
            return True

        served = {
            "axis0.config.watchdog_timeout": (lambda: self.watchdog_timeout_s, set_watchdog_timeout),
            "axis0.config.enable_watchdog": (lambda: self.enable_watchdog, set_enable_watchdog),
            "axis0.controller.config.input_mode": (lambda: int(self.input_mode), set_input_mode),
            "axis0.controller.config.pos_gain": (lambda: self.pos_gain, set_gain("pos_gain")),
            "axis0.controller.config.vel_gain": (lambda: self.vel_gain, set_gain("vel_gain")),
            "axis0.controller.config.vel_integrator_gain": (lambda: self.vel_integrator_gain,
                                                            set_gain("vel_integrator_gain")),
            "axis0.current_state": (lambda: int(self.state), None),
            "axis0.requested_state": (lambda: 0, set_requested_state),
            "axis0.pos_estimate": (lambda: self.encoder_estimates()[0], None),
            "axis0.vel_estimate": (lambda: self.encoder_estimates()[1], None),
            "axis0.config.can.node_id": (lambda: self.node_id, None),
        }
        by_path = {e.path: e for e in ENDPOINTS_BY_ID.values()}
        return {by_path[path].id: (by_path[path], get, put) for path, (get, put) in served.items()}

    def _on_rxsdo(self, data, now_s) -> bool:
        """RxSdo: read (answered with TxSdo, sent from :meth:`handle`) or write an endpoint. An
        endpoint this driver does not serve is answered with nothing (as ODrive does) and counted."""
        opcode, endpoint_id, _reserved, raw = self._codecs[self._rxsdo_cmd].unpack(data)
        entry = self._sdo_endpoints.get(int(endpoint_id))
        if entry is None:
            self.stats["sdo_unknown_endpoint"] += 1
            return True
        endpoint, getter, setter = entry
        if opcode == SDO_OPCODE_READ:
            self.stats["sdo_reads"] += 1
            value = getter()
            bits = sdo_value_bits(value) if endpoint.type == "float" else int(value)
            self._sdo_reply = self._frame(self._txsdo_cmd, self._txsdo_codec, (0, endpoint.id, 0, bits))
            return True
        if opcode != SDO_OPCODE_WRITE:
            return False
        if setter is None:  # a read-only endpoint: ODrive ignores the write
            self.stats["unsupported"] += 1
            return True
        try:
            value = sdo_bits_value(int(raw)) if endpoint.type == "float" else endpoint.from_raw(int(raw))
        except ValueError:
            return False
        self._sdo_now_s = now_s
        if not setter(value):
            return False
        self.stats["sdo_writes"] += 1
        return True

    def _on_set_traj_vel_limit(self, data, now_s) -> bool:
        (limit,) = self._codecs[self._traj_vel_cmd].unpack(data)
        if not (math.isfinite(limit) and limit > 0.0):
            return False
        self.traj_vel_limit = limit
        return True

    def _on_set_traj_accel_limits(self, data, now_s) -> bool:
        accel, decel = self._codecs[self._traj_accel_cmd].unpack(data)
        if not (_finite(accel, decel) and accel > 0.0 and decel > 0.0):
            return False
        self.traj_accel_limit = accel
        self.traj_decel_limit = decel
        return True

    def _on_set_traj_inertia(self, data, now_s) -> bool:
        (inertia,) = self._codecs[self._traj_inertia_cmd].unpack(data)
        if not (math.isfinite(inertia) and inertia >= 0.0):
            return False
        self.traj_inertia = inertia
        return True

    def _on_enter_dfu_mode(self, data, now_s) -> bool:
        """Enter_DFU_Mode: refused (a simulated board has no bootloader), counted, no other effect."""
        self.stats["dfu_refused"] += 1
        return True

    def _set_input_mode(self, mode: InputMode) -> None:
        if mode is not self.input_mode:
            self._cancel_trajectory()
        self.input_mode = mode

    def _cancel_trajectory(self) -> None:
        """Stop following a trajectory (the position input stays the move's target, as ODrive's input_pos)."""
        if self._traj is not None:
            self._traj = None
            self.trajectory_done = True

    def _start_trajectory(self, target: float, now_s: float) -> None:
        """TRAP_TRAJ: plan from the current setpoint (at rest, or where a running move is now) to ``target``."""
        traj = self._traj
        if traj is not None:
            start, vel, _acc = traj.eval(now_s - self._traj_t0_s)
        else:
            start, vel = self.input_pos_rev, 0.0  # the setpoint held at rest (called before input_pos changes)
        self._traj = TrapezoidalTrajectory(target, start, vel, self.traj_vel_limit, self.traj_accel_limit,
                                           self.traj_decel_limit)
        self._traj_t0_s = now_s
        self.trajectory_done = False

    def _address_values(self) -> tuple:
        return (self.node_id, self._serial_number)

    # ------------------------------------------------------------------ reply values (DBC signal order)
    def _version_values(self) -> tuple:
        hw, fw = self.config.hw_version, self.config.fw_version
        return (PROTOCOL_VERSION, hw[0], hw[1], hw[2], fw[0], fw[1], fw[2], 0)

    def _heartbeat_values(self) -> tuple:
        return (int(self.errors | self.disarm_reason), int(self.state), int(self.procedure_result),
                1 if self.trajectory_done else 0)

    def _error_values(self) -> tuple:
        return (int(self.errors), int(self.disarm_reason))

    def _iq_values(self) -> tuple:
        return (self.motor.iq_setpoint_a, self.motor.iq_measured_a)

    def _temperature_values(self) -> tuple:
        return self.thermal.temperature_values()

    def _bus_values(self) -> tuple:
        return self.thermal.bus_values()

    def _torque_values(self) -> tuple:
        return (self.torque_setpoint_nm, self.motor.torque_estimate_nm)

    def _power_values(self) -> tuple:
        return (self.motor.electrical_power_w, self.motor.mechanical_power_w)

    # ------------------------------------------------------------------ control loop
    def update(self, now_s: float, dt_s: float) -> None:
        """One control step at physics rate: watchdog, position-limit check, the cascade, the motor torque."""
        self.thermal.step(dt_s)  # the heat of the current applied over the step just simulated
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
            traj = self._traj
            if traj is None:
                pos_set, vel_set, torque_ff = self.input_pos_rev, self.input_vel_rev_s, self.input_torque_nm
            else:
                # TRAP_TRAJ: the move's setpoints, its acceleration times Set_Traj_Inertia fed forward.
                t = now_s - self._traj_t0_s
                pos_set, vel_set, acc = traj.eval(t)
                torque_ff = acc * self.traj_inertia
                if traj.done(t):
                    self._traj = None
                    self.trajectory_done = True
            vel_des = vel_set
            if mode is _POSITION_CONTROL:
                vel_des += self.pos_gain * (pos_set - pos)
            if vel_des > vel_limit:
                vel_des = vel_limit
            elif vel_des < -vel_limit:
                vel_des = -vel_limit
            v_err = vel_des - vel
            torque = torque_ff + self.vel_gain * v_err + self.vel_integrator_nm
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
            # (Get_Encoder_Estimates is two float32s: _pack_enc is the struct's pack, the same bytes)
            out.append(data_frame(self._enc_id, self._pack_enc(*self.encoder_estimates())))
        period = self._health_period_s
        if period > 0.0 and now_s >= self._next_health - _SCHEDULE_EPS_S:
            nxt = self._next_health + period
            self._next_health = nxt if nxt > now_s else now_s + period
            for cmd in (Cmd.GET_TEMPERATURE, Cmd.GET_BUS_VOLTAGE_CURRENT, Cmd.GET_IQ):
                out.append(self._frame(cmd, self._codecs[cmd], self._getters[cmd]()))
        return out
