"""The controller's configuration: :class:`ControllerConfig`, the whole controller, made of the
configurations that live beside their modules (:class:`~controller.io.axis.AxisConfig`,
:class:`~controller.motion.cpg.CpgConfig`, ...). Frozen dataclasses, SI units in every name; each
field's unit, range and meaning are declared once, with the field
(:mod:`controller.settings.schema`), and checked on creation."""

from __future__ import annotations

from dataclasses import dataclass, field

from controller.io.axis import AxisConfig
from controller.io.health import HealthConfig
from controller.motion.cpg import CpgConfig
from controller.motion.gait import GaitConfig
from controller.motion.kinematics import LegGeometry
from controller.settings.schema import check_settings, setting
from controller.stepping.encoder import RangeEncoderConfig
from controller.stepping.height import HeightEstimatorConfig
from controller.stepping.learner import LearnerConfig
from controller.stepping.range_filter import RangeFilterConfig
from controller.stepping.reflexes import ReflexConfig
from protocol import SENSOR_BOARD_NODE_ID


def default_axes() -> tuple[AxisConfig, AxisConfig]:
    return (
        AxisConfig("hip", node_id=0, min_rad=-0.75, max_rad=1.25, gear_ratio=6.0, direction=1),
        AxisConfig("knee", node_id=1, min_rad=-2.15, max_rad=0.0, gear_ratio=6.0, direction=-1),
    )


@dataclass(frozen=True)
class ControllerConfig:
    """The whole controller: the hip and knee axes, the model's parts (``geometry``, ``cpg``,
    ``gait``, ``range_filter``, ``encoder``, ``learner``, ``height``, ``reflexes``), the drivers'
    runtime health bounds (``health``, :mod:`controller.io.health`), and the loop and
    supervision settings declared below.

    ``sensor_node_id`` is the bus contract's :data:`protocol.SENSOR_BOARD_NODE_ID`, not a setting.
    The default ``heartbeat_period_s`` is ODrive's ``heartbeat_msg_rate_ms`` = 100 and the sensor
    board's 10 Hz. Any accepted frame is a sign of life (``silence_periods``), so random frame loss
    does not look like silence; a node whose heartbeat alone stops (``stale_heartbeat_periods``) is
    lost too, its reported state no longer known.

    ``auto_arm``: the loop requests the arm itself in the tick it first finds every node heard
    (INACTIVE), as the lockstep experiments and the HIL sessions on vcan need; otherwise only an
    operator's arm command arms the axes (:meth:`controller.loop.ControlLoop.request_arm`). The
    settings file refuses it on a real bus (:mod:`controller.settings.file`).
    """

    rate_hz: float = setting(500.0, "Hz", 10.0, 5000.0, "control loop rate")
    axes: tuple[AxisConfig, ...] = field(default_factory=default_axes)
    geometry: LegGeometry = LegGeometry()
    cpg: CpgConfig = CpgConfig()
    gait: GaitConfig = GaitConfig()
    range_filter: RangeFilterConfig = RangeFilterConfig()
    encoder: RangeEncoderConfig = RangeEncoderConfig()
    learner: LearnerConfig = LearnerConfig()
    height: HeightEstimatorConfig = HeightEstimatorConfig()
    reflexes: ReflexConfig = ReflexConfig()
    health: HealthConfig = HealthConfig()
    sensor_node_id: int = SENSOR_BOARD_NODE_ID
    heartbeat_period_s: float = setting(
        0.1, "s", 0.001, 10.0, "the nodes' heartbeat period (ODrive axis.config.can.heartbeat_msg_rate_ms / 1000)")
    silence_periods: float = setting(3.5, "heartbeat periods", 1.0, 100.0,
                                     "a node with no valid frame for this long is lost (safe stop)")
    stale_heartbeat_periods: float = setting(10.0, "heartbeat periods", 1.0, 1000.0,
                                             "a node with no heartbeat for this long is lost")
    bringup_timeout_s: float = setting(5.0, "s", 0.01, 600.0, "give up bringing the axes up after this long")
    late_factor: float = setting(1.5, "control periods", 1.0, 100.0, "a tick longer than this is late")
    max_dt_factor: float = setting(2.0, "control periods", 1.0, 100.0, "the CPG integrates at most this much per tick")
    auto_arm: bool = setting(False, doc="arm by itself once every node is heard; only on a virtual or vcan bus")

    def __post_init__(self) -> None:
        check_settings(self)
        names = [a.name for a in self.axes]
        if sorted(names) != ["hip", "knee"]:
            raise ValueError(f"axes must be exactly hip and knee, got {names}")
        if self.stale_heartbeat_periods < self.silence_periods:
            raise ValueError(f"stale_heartbeat_periods must be at least silence_periods = {self.silence_periods} "
                             f"heartbeat periods, got {self.stale_heartbeat_periods!r}")
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


__all__ = ["ControllerConfig", "default_axes"]
