"""The motor model, kept apart from the robot: transmission, torque limit and electrical estimates.

Like PyBullet's minitaur example, the plant only knows joints (radians, N·m at the joint); this
module turns a driver's motor-side quantities (turns of the motor shaft, N·m at the rotor, amps)
into joint quantities and back. :class:`MotorJoint` binds one plant joint to a
:class:`Transmission` and a :class:`MotorParams`; the simulated ODrive talks only to it.

Sign and unit conventions:

- motor position ``pos_rev = zero_offset_rev + direction * gear_ratio * q_rad / (2*pi)``;
- motor velocity ``vel_rev_s = direction * gear_ratio * qd_rad_s / (2*pi)``;
- joint torque ``tau_joint = tau_motor * gear_ratio * direction`` (an ideal, lossless gearbox).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, Protocol
from protocol.compiled import interpreted

TWO_PI: Final = 2.0 * math.pi  # (Final: a C global when compiled, not a module-dict lookup per use)


class JointPlant(Protocol):
    """What a motor needs from the plant: one joint's state and a torque input."""

    def joint_state(self, name: str) -> tuple[float, float]:
        """``(q_rad, qd_rad_s)`` of the named joint."""
        ...

    def set_joint_torque(self, name: str, tau_nm: float) -> None:
        """Joint-side torque (N·m) applied until the next call."""
        ...


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class Transmission:
    """Gearbox between the motor shaft and the joint.

    ======================  ======  =========  ===========================================
    Field                   Unit    Default    Meaning
    ======================  ======  =========  ===========================================
    ``gear_ratio``          –       ``6.0``    motor revolutions per joint revolution (> 0)
    ``direction``           –       ``1``      +1 or -1: sign of motor turns per joint turn
    ``zero_offset_rev``     rev     ``0.0``    motor encoder reading at joint angle 0
    ======================  ======  =========  ===========================================
    """

    gear_ratio: float = 6.0
    direction: int = 1
    zero_offset_rev: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gear_ratio) and self.gear_ratio > 0.0):
            raise ValueError(f"gear_ratio must be finite and > 0, got {self.gear_ratio!r}")
        if self.direction not in (1, -1):
            raise ValueError(f"direction must be +1 or -1, got {self.direction!r}")
        if not math.isfinite(self.zero_offset_rev):
            raise ValueError(f"zero_offset_rev must be finite, got {self.zero_offset_rev!r}")

    def joint_to_motor_rev(self, q_rad: float) -> float:
        """Motor position (rev) at joint angle ``q_rad`` (rad)."""
        return self.zero_offset_rev + self.direction * self.gear_ratio * q_rad / TWO_PI

    def motor_rev_to_joint_rad(self, pos_rev: float) -> float:
        """Joint angle (rad) at motor position ``pos_rev`` (rev); inverse of :meth:`joint_to_motor_rev`."""
        return (pos_rev - self.zero_offset_rev) * TWO_PI / (self.gear_ratio * self.direction)

    def joint_vel_to_motor(self, qd_rad_s: float) -> float:
        """Motor velocity (rev/s) at joint velocity ``qd_rad_s`` (rad/s)."""
        return self.direction * self.gear_ratio * qd_rad_s / TWO_PI

    def motor_torque_to_joint(self, tau_motor_nm: float) -> float:
        """Joint torque (N·m) produced by rotor torque ``tau_motor_nm`` (N·m): ``tau*gear*direction``."""
        return tau_motor_nm * self.gear_ratio * self.direction


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class MotorParams:
    """Electrical and torque parameters of a BLDC motor (defaults: ODrive D5065-like, KV 100).

    ==============================  ======  =========  ==========================================
    Field                           Unit    Default    Meaning
    ==============================  ======  =========  ==========================================
    ``torque_constant_nm_per_a``    N·m/A   ``0.083``  Kt, rotor torque per amp of Iq (8.27 / KV)
    ``current_limit_a``             A       ``20.0``   hardware Iq limit; rotor torque is clamped
                                                       to ±Kt·limit (1.66 N·m by default)
    ``bus_voltage_v``               V       ``24.0``   DC bus voltage (constant supply)
    ``phase_resistance_ohm``        Ω       ``0.04``   winding resistance; copper loss = Iq²·R
    ==============================  ======  =========  ==========================================
    """

    torque_constant_nm_per_a: float = 0.083
    current_limit_a: float = 20.0
    bus_voltage_v: float = 24.0
    phase_resistance_ohm: float = 0.04

    def __post_init__(self) -> None:
        for name in ("torque_constant_nm_per_a", "current_limit_a", "bus_voltage_v"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.phase_resistance_ohm) and self.phase_resistance_ohm >= 0.0):
            raise ValueError(f"phase_resistance_ohm must be finite and >= 0, got {self.phase_resistance_ohm!r}")

    @property
    def max_torque_nm(self) -> float:
        """Largest rotor torque the motor can produce (N·m): Kt · current limit."""
        return self.torque_constant_nm_per_a * self.current_limit_a


class MotorJoint:
    """One motor driving one plant joint through a transmission.

    Attributes updated by :meth:`apply_motor_torque` (all motor side):

    - ``iq_setpoint_a``: requested torque / Kt (before the hardware current clamp);
    - ``iq_measured_a``: applied torque / Kt (after the clamp);
    - ``torque_estimate_nm``: applied rotor torque;
    - ``mechanical_power_w``: applied torque · shaft speed (rad/s);
    - ``electrical_power_w``: copper loss Iq²·R + mechanical power (negative when regenerating);
    - ``bus_current_a``: electrical power / bus voltage.
    """

    def __init__(
        self,
        plant: JointPlant,
        joint_name: str,
        transmission: Transmission | None = None,
        motor_params: MotorParams | None = None,
    ) -> None:
        self.plant = plant
        self.joint_name = joint_name
        self.transmission = transmission if transmission is not None else Transmission()
        self.params = motor_params if motor_params is not None else MotorParams()
        self._kt = self.params.torque_constant_nm_per_a
        self._tau_max = self.params.max_torque_nm
        self._tau_requested = 0.0
        self._vel_rev_s = 0.0
        self.torque_estimate_nm = 0.0

    @property
    def transmission(self) -> Transmission:
        return self._transmission

    @transmission.setter
    def transmission(self, transmission: Transmission) -> None:
        # The per-step conversions below inline the Transmission formulas with these constants
        # (same operations in the same order, so the same floats as the Transmission methods).
        self._transmission = transmission
        self._zero_offset_rev = transmission.zero_offset_rev
        self._gear_ratio = transmission.gear_ratio
        self._direction = transmission.direction
        self._dir_gear = transmission.direction * transmission.gear_ratio

    @property
    def motor_params(self) -> MotorParams:
        return self.params

    @property
    def max_torque_nm(self) -> float:
        """Hardware rotor torque limit (N·m)."""
        return self._tau_max

    def motor_state(self) -> tuple[float, float]:
        """``(pos_rev, vel_rev_s)`` of the motor shaft, read from the plant joint."""
        q, qd = self.plant.joint_state(self.joint_name)
        # Transmission.joint_to_motor_rev and .joint_vel_to_motor, inlined (hot path).
        dir_gear = self._dir_gear
        return self._zero_offset_rev + dir_gear * q / TWO_PI, dir_gear * qd / TWO_PI

    def apply_motor_torque(self, tau_nm: float, vel_rev_s: float | None = None) -> float:
        """Apply rotor torque ``tau_nm`` (clamped to ±Kt·current limit) to the joint.

        ``vel_rev_s`` is the shaft speed used for the power estimate; when None it is read from
        the plant. A non-finite request is treated as zero. Returns the applied rotor torque.
        """
        if math.isinf(tau_nm) or math.isnan(tau_nm):  # not isfinite: compiled, these two are C calls, it is not
            tau_nm = 0.0
        tau_max = self._tau_max
        applied = tau_max if tau_nm > tau_max else (-tau_max if tau_nm < -tau_max else tau_nm)
        # Transmission.motor_torque_to_joint, inlined (hot path).
        self.plant.set_joint_torque(self.joint_name, applied * self._gear_ratio * self._direction)
        if vel_rev_s is None:
            vel_rev_s = self.transmission.joint_vel_to_motor(self.plant.joint_state(self.joint_name)[1])
        self._tau_requested = tau_nm
        self.torque_estimate_nm = applied
        self._vel_rev_s = vel_rev_s
        return applied

    # Derived readings, computed when asked (Get_Iq, Get_Powers, Get_Bus_Voltage_Current), not
    # on every physics step.
    @property
    def iq_setpoint_a(self) -> float:
        return self._tau_requested / self._kt

    @property
    def iq_measured_a(self) -> float:
        return self.torque_estimate_nm / self._kt

    @property
    def mechanical_power_w(self) -> float:
        return self.torque_estimate_nm * self._vel_rev_s * TWO_PI

    @property
    def electrical_power_w(self) -> float:
        iq = self.iq_measured_a
        return iq * iq * self.params.phase_resistance_ohm + self.mechanical_power_w

    @property
    def bus_current_a(self) -> float:
        return self.electrical_power_w / self.params.bus_voltage_v
