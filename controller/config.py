"""Controller configuration: frozen dataclasses, SI units in every name, validated on creation."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from controller.stepping.encoder import RangeEncoderConfig
from controller.stepping.height import HeightEstimatorConfig
from controller.stepping.learner import LearnerConfig
from controller.stepping.range_filter import RangeFilterConfig
from controller.stepping.reflexes import ReflexConfig


def _check(name: str, value: float, lo: float, hi: float, unit: str) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"{name} must be in [{lo}, {hi}] {unit}, got {value!r}")


@dataclass(frozen=True)
class AxisConfig:
    """One joint driven by one ODrive axis.

    Attributes:
        name: joint name ("hip" or "knee").
        node_id: the axis's CAN node id (0..63, not 16: that is the sensor board).
        gear_ratio: motor revolutions per joint revolution; default 6.0.
        direction: +1 or -1, the sign from joint angle to motor angle; default +1.
        zero_offset_rev: motor position [rev] at joint angle 0 (calibration); default 0.0.
        min_rad, max_rad: the joint's allowed range [rad]; no target outside it is ever sent.
        current_limit_a: the motor current limit sent to the axis with Set_Limits at arming
            (ODrive's ``motor.config.current_lim`` at run time) [A]; it bounds the torque to
            Kt times this. Default 20.0, the simulated drivers' hardware limit (a lower value
            lowers their torque clamp, a higher one is capped by the hardware).
        vel_limit_rev_s: the velocity limit sent with Set_Limits at arming (ODrive's
            ``controller.config.vel_limit``, motor side) [rev/s]; default 20.0, the simulated
            drivers' own default. Keep it well below ``FeedbackLimits.max_vel_rev_s`` (100):
            faster encoder readings are taken for corrupted frames.
    """

    name: str
    node_id: int
    min_rad: float
    max_rad: float
    gear_ratio: float = 6.0
    direction: int = 1
    zero_offset_rev: float = 0.0
    current_limit_a: float = 20.0
    vel_limit_rev_s: float = 20.0

    def __post_init__(self) -> None:
        _check(f"axes.{self.name}.node_id", self.node_id, 0, 63, "")
        if self.node_id == 16:
            raise ValueError(f"axes.{self.name}.node_id 16 is the sensor board's")
        _check(f"axes.{self.name}.gear_ratio", self.gear_ratio, 0.1, 1000.0, "rev/rev")
        if self.direction not in (1, -1):
            raise ValueError(f"axes.{self.name}.direction must be +1 or -1, got {self.direction!r}")
        if not self.min_rad < self.max_rad:
            raise ValueError(f"axes.{self.name}: min_rad {self.min_rad} must be below max_rad {self.max_rad}")
        _check(f"axes.{self.name}.current_limit_a", self.current_limit_a, 0.1, 200.0, "A")
        _check(f"axes.{self.name}.vel_limit_rev_s", self.vel_limit_rev_s, 0.1, 80.0, "rev/s")

    def rad_to_rev(self, q_rad: float) -> float:
        return self.zero_offset_rev + self.direction * self.gear_ratio * q_rad / (2.0 * math.pi)

    def rev_to_rad(self, pos_rev: float) -> float:
        return (pos_rev - self.zero_offset_rev) * 2.0 * math.pi / (self.direction * self.gear_ratio)

    def rad_s_to_rev_s(self, qd_rad_s: float) -> float:
        return self.direction * self.gear_ratio * qd_rad_s / (2.0 * math.pi)

    def rev_s_to_rad_s(self, vel_rev_s: float) -> float:
        return vel_rev_s * 2.0 * math.pi / (self.direction * self.gear_ratio)


@dataclass(frozen=True)
class LegGeometry:
    """Leg dimensions the controller's kinematics assume.

    Attributes:
        thigh_m: hip-to-knee length [m]; default 0.25.
        shank_m: knee-to-foot-centre length [m]; default 0.25.
        hip_height_m: hip axis above the ground [m]; default 0.47.
        foot_radius_m: foot sphere radius [m]; default 0.02.
    """

    thigh_m: float = 0.25
    shank_m: float = 0.25
    hip_height_m: float = 0.47
    foot_radius_m: float = 0.02


@dataclass(frozen=True)
class CpgConfig:
    """The ring oscillator.

    Attributes:
        stance_s: duration of the extension (stance) half of the ring [s]; default 0.40.
        burst_s: base burst length, the flexion (swing) duration [s]; default 0.30.
        burst_min_s, burst_max_s: safe bounds on the modulated burst length [s]; 0.15, 0.60.
        activation_tau_s: time constant of each unit's rate output [s]; default 0.02.
        units_per_half: ring units in the extension half and in the flexion half; default 2.
    """

    stance_s: float = 0.40
    burst_s: float = 0.30
    burst_min_s: float = 0.15
    burst_max_s: float = 0.60
    activation_tau_s: float = 0.02
    units_per_half: int = 2

    def __post_init__(self) -> None:
        _check("cpg.stance_s", self.stance_s, 0.05, 5.0, "s")
        _check("cpg.burst_min_s", self.burst_min_s, 0.05, 5.0, "s")
        _check("cpg.burst_max_s", self.burst_max_s, self.burst_min_s, 5.0, "s")
        _check("cpg.burst_s", self.burst_s, self.burst_min_s, self.burst_max_s, "s")
        _check("cpg.units_per_half", self.units_per_half, 1, 8, "")


@dataclass(frozen=True)
class GaitConfig:
    """Foot trajectory shaping.

    Attributes:
        ground_speed_m_s: speed of the ground under the hip (the rail speed) that the stance
            foot matches [m/s]; default 0.5.
        foot_ahead_m: foot x at touchdown, ahead of the point below the hip [m]; default 0.10.
        step_height_m: foot lift at full CPG amplitude over flat ground [m]; default 0.08.
        stance_press_m: how far below the ground the stance target sits, for a firm contact [m];
            default 0.005.
        muscle_tau_s: time constant of the muscle low-pass on the joint targets [s]; 0.015.
        ramp_s: time to move from the pose found at bring-up to the gait's start pose [s]; 1.0.
    """

    ground_speed_m_s: float = 0.5
    foot_ahead_m: float = 0.10
    step_height_m: float = 0.08
    stance_press_m: float = 0.005
    muscle_tau_s: float = 0.015
    ramp_s: float = 1.0

    def __post_init__(self) -> None:
        _check("gait.ground_speed_m_s", self.ground_speed_m_s, 0.0, 3.0, "m/s")
        _check("gait.step_height_m", self.step_height_m, 0.0, 0.3, "m")
        _check("gait.muscle_tau_s", self.muscle_tau_s, 0.0, 1.0, "s")
        _check("gait.ramp_s", self.ramp_s, 0.0, 10.0, "s")


def default_axes() -> tuple[AxisConfig, AxisConfig]:
    return (
        AxisConfig("hip", node_id=0, min_rad=-0.75, max_rad=1.25, gear_ratio=6.0, direction=1),
        AxisConfig("knee", node_id=1, min_rad=-2.15, max_rad=0.0, gear_ratio=6.0, direction=-1),
    )


@dataclass(frozen=True)
class ControllerConfig:
    """The whole controller.

    Attributes:
        rate_hz: control loop rate [Hz]; default 500.
        axes: the hip and knee axes (see :class:`AxisConfig`).
        sensor_node_id: the sensor board's node id; default 16.
        range_filter: the Kalman filter on the range readings.
        encoder: the range encoder's cells.
        learner: gated memory, traces and learning rule.
        height: the obstacle-height estimator (context from the range profile).
        reflexes: contact reflexes and the lift reflex.
        heartbeat_period_s: the nodes' heartbeat period [s]; default 0.1 (ODrive's
            ``heartbeat_msg_rate_ms`` = 100, the sensor board's 10 Hz).
        silence_periods: a node from which no valid frame at all has arrived for this many
            heartbeat periods is lost (safe stop); default 3.5 (0.35 s). Any accepted frame is a
            sign of life, so random frame loss does not look like silence.
        stale_heartbeat_periods: a node whose heartbeat alone has not arrived for this many
            periods is lost too (its reported state is no longer known); default 10 (1 s).
        bringup_timeout_s: give up bringing the axes up after this long [s]; default 5.0.
        late_factor: a tick whose measured period exceeds this many nominal periods is late;
            default 1.5.
        max_dt_factor: the CPG integrates at most this many nominal periods per tick; default 2.
    """

    rate_hz: float = 500.0
    axes: tuple[AxisConfig, ...] = field(default_factory=default_axes)
    geometry: LegGeometry = LegGeometry()
    cpg: CpgConfig = CpgConfig()
    gait: GaitConfig = GaitConfig()
    range_filter: RangeFilterConfig = RangeFilterConfig()
    encoder: RangeEncoderConfig = RangeEncoderConfig()
    learner: LearnerConfig = LearnerConfig()
    height: HeightEstimatorConfig = HeightEstimatorConfig()
    reflexes: ReflexConfig = ReflexConfig()
    sensor_node_id: int = 16
    heartbeat_period_s: float = 0.1
    silence_periods: float = 3.5
    stale_heartbeat_periods: float = 10.0
    bringup_timeout_s: float = 5.0
    late_factor: float = 1.5
    max_dt_factor: float = 2.0

    def __post_init__(self) -> None:
        _check("rate_hz", self.rate_hz, 10.0, 5000.0, "Hz")
        names = [a.name for a in self.axes]
        if sorted(names) != ["hip", "knee"]:
            raise ValueError(f"axes must be exactly hip and knee, got {names}")
        _check("heartbeat_period_s", self.heartbeat_period_s, 0.001, 10.0, "s")
        _check("silence_periods", self.silence_periods, 1.0, 100.0, "periods")
        _check("stale_heartbeat_periods", self.stale_heartbeat_periods, self.silence_periods, 1000.0, "periods")
        ids = [a.node_id for a in self.axes]
        if len(set(ids)) != len(ids):
            raise ValueError(f"axes node ids must differ, got {ids}")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def heartbeat_timeout_s(self) -> float:
        """A node with no valid frame for this long is lost [s]."""
        return self.silence_periods * self.heartbeat_period_s

    @property
    def stale_heartbeat_s(self) -> float:
        """A node with no heartbeat for this long is lost [s]."""
        return self.stale_heartbeat_periods * self.heartbeat_period_s

    def axis(self, name: str) -> AxisConfig:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(name)
