"""One ODrive axis as the controller sees it: its feedback and the frames that command it.

Feedback arrives from Heartbeat and Get_Encoder_Estimates frames and is converted to joint
units through the axis's gear ratio, direction and zero offset. Every position command passes
through :meth:`AxisLink.pos_frame`, which clamps the target into ``[min_rad, max_rad]``: no code
path can put a joint target outside the configured limits on the bus.
"""

from __future__ import annotations

import math

import can

from controller.config import AxisConfig
from protocol import AxisState, BusContract, ControlMode, InputMode, data_frame


class AxisLink:
    def __init__(self, config: AxisConfig, contract: BusContract) -> None:
        self.config = config
        self.name = config.name
        node = config.node_id
        self._pos = contract.codec("Set_Input_Pos")
        self._state = contract.codec("Set_Axis_State")
        self._mode = contract.codec("Set_Controller_Mode")
        self._clear = contract.codec("Clear_Errors")
        self._estop = contract.codec("Estop")
        self.pos_id = contract.odrive_id(node, "Set_Input_Pos")
        self.state_id = contract.odrive_id(node, "Set_Axis_State")
        self.mode_id = contract.odrive_id(node, "Set_Controller_Mode")
        self.clear_id = contract.odrive_id(node, "Clear_Errors")
        self.estop_id = contract.odrive_id(node, "Estop")
        self.heartbeat_id = contract.odrive_id(node, "Heartbeat")
        self.encoder_id = contract.odrive_id(node, "Get_Encoder_Estimates")
        # joint <-> motor unit factors, precomputed for the 500 Hz path
        self._rev_per_rad = config.direction * config.gear_ratio / (2.0 * math.pi)
        self._rad_per_rev = 1.0 / self._rev_per_rad
        self._offset_rev = config.zero_offset_rev
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

    # -- feedback ------------------------------------------------------------------------
    def on_heartbeat(self, values: tuple, now_s: float) -> bool:
        error, state, result, _done = values
        self.error = int(error)
        try:
            self.state = AxisState(int(state))
        except ValueError:
            return False
        self.procedure_result = int(result)
        self.heartbeat_t_s = now_s
        return True

    def on_encoder(self, values: tuple, now_s: float) -> bool:
        pos_rev, vel_rev_s = values
        if not (math.isfinite(pos_rev) and math.isfinite(vel_rev_s)):
            return False
        self.pos_rad = (pos_rev - self._offset_rev) * self._rad_per_rev
        self.vel_rad_s = vel_rev_s * self._rad_per_rev
        self.encoder_t_s = now_s
        return True

    @property
    def closed_loop(self) -> bool:
        return self.state == AxisState.CLOSED_LOOP_CONTROL and self.error == 0

    # -- commands ------------------------------------------------------------------------
    def clamp(self, q_rad: float) -> float:
        c = self.config
        if c.min_rad <= q_rad <= c.max_rad:
            return q_rad
        if not math.isfinite(q_rad):
            # a NaN target is never sent: hold the last target (or the measured position)
            self.clamped_targets += 1
            fallback = self.last_target_rad if math.isfinite(self.last_target_rad) else self.pos_rad
            return min(c.max_rad, max(c.min_rad, fallback if math.isfinite(fallback) else 0.0))
        if q_rad < c.min_rad or q_rad > c.max_rad:
            self.clamped_targets += 1
            return c.min_rad if q_rad < c.min_rad else c.max_rad
        return q_rad

    def pos_frame(self, q_rad: float, qd_rad_s: float = 0.0) -> can.Message:
        q = self.clamp(q_rad)
        self.last_target_rad = q
        vel_ff = qd_rad_s * self._rev_per_rad if math.isfinite(qd_rad_s) else 0.0
        vel_ff = 32.0 if vel_ff > 32.0 else (-32.0 if vel_ff < -32.0 else vel_ff)
        data = self._pos.pack(self._offset_rev + q * self._rev_per_rad, vel_ff, 0.0)
        return data_frame(self.pos_id, data)

    def state_frame(self, state: AxisState) -> can.Message:
        return data_frame(self.state_id, self._state.pack(int(state)))

    def mode_frame(self, control: ControlMode, input_mode: InputMode) -> can.Message:
        data = self._mode.pack(int(control), int(input_mode))
        return data_frame(self.mode_id, data)

    def clear_errors_frame(self) -> can.Message:
        return data_frame(self.clear_id, self._clear.pack(0))

    def estop_frame(self) -> can.Message:
        return data_frame(self.estop_id, b"")
