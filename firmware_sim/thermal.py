"""What a driver's health readings measure: motor and FET temperatures, and the DC bus voltage.

:class:`ThermalModel` belongs to one simulated ODrive axis (:class:`~firmware_sim.odrive_axis.
SimOdriveAxis`, attribute ``thermal``), is stepped with it at physics rate from the motor's
applied current, and gives Get_Temperature and Get_Bus_Voltage_Current their values. It never
acts on the physics: no derating, no trip (the drivers' own thermal and undervoltage trips are not
simulated; the controller's bounds, :mod:`controller.io.health`, are what stops the leg).

- **Motor winding**, first order: ``tau_m dT/dt = T_amb + R_th,m * P_m - T`` with the copper loss
  ``P_m = Iq^2 * R_phase + extra_motor_loss_w`` (the motor model's phase resistance, the same
  loss :class:`~firmware_sim.motor.MotorJoint` counts). At the 20 A hardware limit (a motor held
  against a stop) that is 16 W: 32 K above ambient at the default 2 K/W, reached with a 60 s time
  constant. ``extra_motor_loss_w`` is a fault to inject (a shorted turn, a seized bearing): heat
  without current.
- **FET**, first order the same way with ``P_f = Iq^2 * fet_resistance_ohm`` (conduction loss
  of the bridge) plus ``fet_idle_loss_w``, a faster time constant (a small thermal mass).
- **Bus voltage** sags under load: ``V = V_source - R_source * I_bus``, with the motor model's
  bus current (electrical power over the nominal bus voltage; negative, and the voltage rising,
  while regenerating).

The integration is exact for a current constant over a step (``T += (T_ss - T) * (1 -
exp(-dt/tau))``), so any step size is stable. ``ambient_c``, ``source_voltage_v`` and
``extra_motor_loss_w`` are plain attributes: a test or a fault row may change them mid-run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_sim.motor import MotorJoint
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class ThermalParams:
    """A driver's thermal and supply model (the simulated leg's defaults, D5065 on an ODrive S1-class board).

    ======================================  =====  =======  ============================================
    Field                                   Unit   Default  Meaning
    ======================================  =====  =======  ============================================
    ``ambient_c``                           C      25.0     air around motor and driver; both start there
    ``motor_thermal_resistance_k_per_w``    K/W    2.0      winding to ambient, steady state
    ``motor_time_constant_s``               s      60.0     winding's thermal time constant
    ``extra_motor_loss_w``                  W      0.0      heat without current (a fault to inject)
    ``fet_resistance_ohm``                  Ω      0.01     bridge conduction loss Iq²·R
    ``fet_idle_loss_w``                     W      0.5      switching and gate-drive loss, always there
    ``fet_thermal_resistance_k_per_w``      K/W    4.0      FET to ambient, steady state
    ``fet_time_constant_s``                 s      20.0     FET's thermal time constant
    ``source_voltage_v``                    V      None     supply's open-circuit voltage; None: the
                                                            motor model's ``bus_voltage_v`` (24 V)
    ``source_resistance_ohm``               Ω      0.2      supply and wiring: the bus sags this much
                                                            per amp drawn
    ======================================  =====  =======  ============================================
    """

    ambient_c: float = 25.0
    motor_thermal_resistance_k_per_w: float = 2.0
    motor_time_constant_s: float = 60.0
    extra_motor_loss_w: float = 0.0
    fet_resistance_ohm: float = 0.01
    fet_idle_loss_w: float = 0.5
    fet_thermal_resistance_k_per_w: float = 4.0
    fet_time_constant_s: float = 20.0
    source_voltage_v: float | None = None
    source_resistance_ohm: float = 0.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.ambient_c) and -60.0 <= self.ambient_c <= 300.0):
            raise ValueError(f"ambient_c must be in [-60, 300] C, got {self.ambient_c!r}")
        for name in ("motor_thermal_resistance_k_per_w", "extra_motor_loss_w", "fet_resistance_ohm",
                     "fet_idle_loss_w", "fet_thermal_resistance_k_per_w", "source_resistance_ohm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name in ("motor_time_constant_s", "fet_time_constant_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        v = self.source_voltage_v
        if v is not None and not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"source_voltage_v must be finite and >= 0 or None, got {v!r}")


class ThermalModel:
    """One driver's temperatures and bus voltage (see the module doc). ``motor_c``, ``fet_c``:
    the states [C]; ``ambient_c``, ``source_voltage_v``, ``extra_motor_loss_w``: the conditions,
    changeable at any time; ``max_motor_c``, ``max_fet_c``, ``min_bus_voltage_v``,
    ``max_bus_voltage_v``: the extremes reported so far (Get_* values), for experiments."""

    def __init__(self, motor: MotorJoint, params: ThermalParams = ThermalParams()) -> None:
        self.motor = motor
        self.params = params
        self.ambient_c = params.ambient_c
        self.extra_motor_loss_w = params.extra_motor_loss_w
        self.source_voltage_v = motor.params.bus_voltage_v if params.source_voltage_v is None else params.source_voltage_v
        self.motor_c = params.ambient_c
        self.fet_c = params.ambient_c
        self._r_phase = motor.params.phase_resistance_ohm
        self._inv_kt = 1.0 / motor.params.torque_constant_nm_per_a
        self._a_m = self._a_f = 0.0
        self.max_motor_c = self.max_fet_c = -math.inf
        self.min_bus_voltage_v = math.inf
        self.max_bus_voltage_v = -math.inf

    @property
    def params(self) -> ThermalParams:
        return self._params

    @params.setter
    def params(self, params: ThermalParams) -> None:
        # The frozen params' constants that step reads every physics step, as plain attributes
        # (hot path); the step factors are recomputed at the next step.
        self._params = params
        self._rth_m = params.motor_thermal_resistance_k_per_w
        self._r_fet = params.fet_resistance_ohm
        self._fet_idle_w = params.fet_idle_loss_w
        self._rth_f = params.fet_thermal_resistance_k_per_w
        self._dt = math.nan

    def step(self, dt_s: float) -> None:
        """Advance by ``dt_s`` with the current the motor applies now (constant over the step)."""
        if dt_s != self._dt:
            p = self._params
            self._dt = dt_s
            self._a_m = -math.expm1(-dt_s / p.motor_time_constant_s)
            self._a_f = -math.expm1(-dt_s / p.fet_time_constant_s)
        iq = self.motor.torque_estimate_nm * self._inv_kt
        i2 = iq * iq
        amb = self.ambient_c
        self.motor_c += (amb + (i2 * self._r_phase + self.extra_motor_loss_w) * self._rth_m - self.motor_c) * self._a_m
        self.fet_c += (amb + (i2 * self._r_fet + self._fet_idle_w) * self._rth_f - self.fet_c) * self._a_f

    @property
    def bus_voltage_v(self) -> float:
        """The DC bus now: the source voltage less the sag across the source resistance."""
        return self.source_voltage_v - self.params.source_resistance_ohm * self.motor.bus_current_a

    def temperature_values(self) -> tuple[float, float]:
        """Get_Temperature's (FET_Temperature, Motor_Temperature) [C]."""
        self.max_fet_c = max(self.max_fet_c, self.fet_c)
        self.max_motor_c = max(self.max_motor_c, self.motor_c)
        return (self.fet_c, self.motor_c)

    def bus_values(self) -> tuple[float, float]:
        """Get_Bus_Voltage_Current's (Bus_Voltage [V], Bus_Current [A])."""
        v = self.bus_voltage_v
        self.min_bus_voltage_v = min(self.min_bus_voltage_v, v)
        self.max_bus_voltage_v = max(self.max_bus_voltage_v, v)
        return (v, self.motor.bus_current_a)


__all__ = ["ThermalModel", "ThermalParams"]
