"""Runtime health of the drivers: bus voltage, FET and motor temperatures and motor current, bounded.

Each ODrive sends its readings cyclically, as firmware 0.6 does for any ``*_msg_rate_ms`` set
above zero: Get_Temperature (``axis.config.can.temperature_msg_rate_ms``: FET and motor
thermistor), Get_Bus_Voltage_Current (``bus_voltage_msg_rate_ms``) and Get_Iq
(``iq_msg_rate_ms``), every :attr:`HealthConfig.read_period_s` (100 ms: the heartbeat's rate, 60
frames a second for two axes, well under 1 % of a 1 Mbit/s bus). The controller sends nothing for
them (no RTR requests, so its own frames and the drivers' watchdogs are as before); each frame is
validated and kept by :class:`~controller.io.axis.AxisLink` (``bus_voltage_v``, ``fet_temp_c``,
``motor_temp_c``, ``iq_a``), and :class:`~controller.supervisor.Supervisor` checks the latest
readings with :func:`health_fault` in every tick of an active phase (ARMING, RAMP, WALK): a
reading beyond its bound is a latched FAULT (the safe stop), its cause naming the axis, the
reading and the bound, e.g. "hip motor temperature 92.3 C above 90 C".

A reading that never came, or stopped coming, is not a health fault: a silent node is the
supervisor's silence timeout, and a driver without a motor thermistor reports NaN (kept as None,
not checked).
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.io.axis import AxisLink
from controller.settings.schema import check_settings, setting
from protocol.compiled import interpreted


@interpreted  # a configuration: plain Python even when compiled (protocol.compiled)
@dataclass(frozen=True)
class HealthConfig:
    """The bounds of the drivers' runtime readings (TOML section ``[health]``).

    The defaults suit a 24 V supply and the ODrive S1 / D5065 class of the rig: the bus within
    18-56 V (the S1 runs on 12-48 V nominal and trips itself above about 58 V), the FET
    thermistor at most 100 C (ODrive's own FET derating starts there), the motor at most 90 C
    (well under a D5065's winding class), and the measured Iq at most 30 A: above the axes'
    ``current_limit_a`` (20 A), so only a driver that fails to hold its own current limit trips
    it. Tighten them for a leg whose supply or motors ask for it (a 48 V supply: raise
    ``min_bus_voltage_v``).
    """

    min_bus_voltage_v: float = setting(18.0, "V", 0.0, 100.0, "a bus voltage below this stops the leg (supply sagging)")
    max_bus_voltage_v: float = setting(56.0, "V", 0.0, 100.0,
                                       "a bus voltage above this stops the leg (regeneration pumping the bus)")
    max_fet_temp_c: float = setting(100.0, "C", 0.0, 200.0, "a driver FET temperature above this stops the leg")
    max_motor_temp_c: float = setting(90.0, "C", 0.0, 200.0,
                                      "a motor temperature (the driver's motor thermistor) above this stops the leg")
    max_current_a: float = setting(30.0, "A", 0.1, 300.0, "a measured motor current (abs Iq) above this stops the leg")
    read_period_s: float = setting(
        0.1, "s", 0.001, 10.0, "the drivers send Get_Temperature, Get_Bus_Voltage_Current and Get_Iq this often "
        "(ODrive temperature_msg_rate_ms, bus_voltage_msg_rate_ms, iq_msg_rate_ms / 1000)")

    def __post_init__(self) -> None:
        check_settings(self, "health")
        if not self.min_bus_voltage_v < self.max_bus_voltage_v:
            raise ValueError(f"health: min_bus_voltage_v {self.min_bus_voltage_v} must be below max_bus_voltage_v "
                             f"{self.max_bus_voltage_v}")


def health_fault(config: HealthConfig, axis: AxisLink) -> str | None:
    """The first bound ``axis`` (an :class:`~controller.io.axis.AxisLink`) is beyond, as the
    fault's cause, or None (a reading not received is not checked)."""
    name = axis.name
    v = axis.bus_voltage_v
    if v is not None:
        if v < config.min_bus_voltage_v:
            return f"{name} bus voltage {v:.1f} V below {config.min_bus_voltage_v:g} V"
        if v > config.max_bus_voltage_v:
            return f"{name} bus voltage {v:.1f} V above {config.max_bus_voltage_v:g} V"
    t = axis.motor_temp_c
    if t is not None and t > config.max_motor_temp_c:
        return f"{name} motor temperature {t:.1f} C above {config.max_motor_temp_c:g} C"
    t = axis.fet_temp_c
    if t is not None and t > config.max_fet_temp_c:
        return f"{name} FET temperature {t:.1f} C above {config.max_fet_temp_c:g} C"
    i = axis.iq_a
    if i is not None and abs(i) > config.max_current_a:
        return f"{name} motor current {abs(i):.1f} A above {config.max_current_a:g} A"
    return None


__all__ = ["HealthConfig", "health_fault"]
