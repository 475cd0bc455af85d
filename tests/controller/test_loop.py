"""The loop's lifecycle: the operator's commands (arm, disarm, estop, clear faults), auto_arm, a
second master, and what each sends on the bus (counted on a FakeBus)."""

from __future__ import annotations

import json
import logging
import math

import pytest

from controller.config import ControllerConfig
from controller.loop import ControlLoop
from controller.supervisor import Phase
from protocol import SENSOR_BOARD_NODE_ID, AxisError, AxisState, BusContract, arbitration_id, data_frame
from protocol.contract import sdo_bits_value, sdo_value_bits
from protocol.endpoints import WATCHDOG_TIMEOUT
from tests.fakes import FakeBus

C = BusContract.load()
RXSDO, TXSDO = C.codec("RxSdo"), C.codec("TxSdo")
HB, ENC, SB_HB = C.codec("Heartbeat"), C.codec("Get_Encoder_Estimates"), C.codec("SB_Heartbeat")
ESTOP = int(AxisError.ESTOP_REQUESTED)


def heartbeat(node: int, state: AxisState = AxisState.IDLE, error: int = 0):
    return data_frame(C.odrive_id(node, "Heartbeat"), HB.pack(error, int(state), 0, 1))


def encoder(node: int, pos_rev: float = 0.0):
    return data_frame(C.odrive_id(node, "Get_Encoder_Estimates"), ENC.pack(pos_rev, 0.0))


def sb_heartbeat():
    return data_frame(arbitration_id(SENSOR_BOARD_NODE_ID, SB_HB.cmd_id), SB_HB.pack(0, 1, 1, 0.0))


class Leg:
    """A leg that answers only with what a test says: each :meth:`tick` pushes a heartbeat per
    axis (its ``states`` and ``errors``), an encoder estimate per axis and the sensor board's
    heartbeat, then ticks the loop."""

    def __init__(self, **config) -> None:
        self.bus = FakeBus()
        self.loop = ControlLoop(ControllerConfig(**config), self.bus)
        self.states = {0: AxisState.IDLE, 1: AxisState.IDLE}
        self.errors = {0: 0, 1: 0}
        self.t = 0.0
        self.quiet: set[int] = set()
        # The drivers' SDO: each answers a read with what was written to it (``watchdog_reads``:
        # a value it answers instead; "silent": no answer at all), the tick after.
        self.watchdog_reads: dict[int, float | str | None] = {0: None, 1: None}
        self.lose_sdo: dict[int, int] = {0: 0, 1: 0}  # the next N RxSdo frames to a node are lost
        self.written: dict[int, int] = {}
        self._sdo_seen = 0

    def _answer_sdo(self) -> None:
        sent = self.bus.sent
        for m in sent[self._sdo_seen:]:
            node, cmd = m.arbitration_id >> 5, m.arbitration_id & 0x1F
            if cmd != RXSDO.cmd_id:
                continue
            opcode, endpoint_id, _reserved, raw = RXSDO.unpack(m.data)
            if self.lose_sdo[node]:
                self.lose_sdo[node] -= 1
                continue
            if opcode == 1:
                self.written[node] = int(raw)
            elif self.watchdog_reads[node] != "silent":
                answer = self.watchdog_reads[node]
                value = self.written.get(node, 0) if answer is None else sdo_value_bits(answer)
                self.bus.push(data_frame(C.odrive_id(node, "TxSdo"), TXSDO.pack(0, int(endpoint_id), 0, value)))
        self._sdo_seen = len(sent)

    def tick(self, n: int = 1, feedback: bool = True) -> None:
        for _ in range(n):
            self._answer_sdo()
            if feedback:
                for node in (0, 1):
                    if node not in self.quiet:
                        self.bus.push(heartbeat(node, self.states[node], self.errors[node]), encoder(node))
                self.bus.push(sb_heartbeat())
            self.loop.tick(self.t)
            self.t += self.loop.config.period_s

    def sent(self, name: str, node: int | None = None) -> int:
        ids = {C.odrive_id(n, name) for n in ((0, 1) if node is None else (node,))}
        return sum(1 for m in self.bus.sent if m.arbitration_id in ids)

    def follow(self) -> None:
        """The drivers do what the last Set_Axis_State asked (when they have no error)."""
        for node in (0, 1):
            for m in self.bus.sent:
                if m.arbitration_id == C.odrive_id(node, "Set_Axis_State"):
                    state = AxisState(C.codec("Set_Axis_State").unpack(m.data)[0])
                    self.states[node] = state if not self.errors[node] else AxisState.IDLE


def test_the_loop_waits_inactive_without_an_arm_command_and_sends_nothing():
    leg = Leg()
    leg.tick(300)
    assert leg.loop.phase is Phase.INACTIVE and leg.loop.lifecycle == "inactive"
    assert leg.bus.sent == []


def test_estop_latched_before_start_refuses_the_arm_naming_the_axis_and_its_error():
    leg = Leg()
    leg.errors[0] = ESTOP
    leg.tick(5)
    assert leg.loop.phase is Phase.INACTIVE  # an error while INACTIVE is not a fault
    reason = leg.loop.request_arm(leg.t)
    assert reason is not None and "hip" in reason and "ESTOP_REQUESTED" in reason and "0x2000000" in reason
    assert "knee" not in reason
    leg.tick(10)
    assert leg.loop.phase is Phase.INACTIVE and leg.bus.sent == []  # nothing sent, Clear_Errors least of all
    st = leg.loop.status()
    assert st["axes"]["hip"]["error_names"] == ["ESTOP_REQUESTED"] and st["axes"]["hip"]["error"] == ESTOP
    assert st["axes"]["knee"]["error_names"] == []


def test_auto_arm_never_clears_a_latched_error():
    leg = Leg(auto_arm=True)
    leg.errors[1] = ESTOP | int(AxisError.WATCHDOG_TIMER_EXPIRED)
    leg.tick(1000)  # two seconds: retried every 0.5 s, always refused
    assert leg.loop.phase is Phase.INACTIVE
    assert leg.sent("Clear_Errors") == 0 and leg.sent("Set_Axis_State") == 0 and leg.sent("Set_Input_Pos") == 0


def arm_and_run(leg, ticks):
    leg.tick(3)
    assert leg.loop.request_arm(leg.t) is None
    for _ in range(ticks):
        leg.tick()
        leg.follow()


def test_arming_sends_no_clear_errors_and_reaches_walk():
    leg = Leg()
    arm_and_run(leg, 800)
    assert leg.loop.phase is Phase.WALK and leg.loop.lifecycle == "active"
    assert leg.sent("Clear_Errors") == 0
    assert leg.sent("Set_Controller_Mode", 0) == 1 and leg.sent("Set_Limits", 0) == 1
    assert leg.sent("Set_Axis_State", 0) == 1 and leg.sent("Set_Input_Pos") > 0


def test_auto_arm_arms_in_the_tick_inactive_is_reached():
    leg = Leg(auto_arm=True)
    phases = []
    for _ in range(3):
        leg.tick()
        phases.append(leg.loop.phase)
        if leg.loop.phase is not Phase.WAIT_NODES:
            break
    # the first tick hears every node: INACTIVE and ARMING in that tick, the arming frames sent in it
    assert phases == [Phase.ARMING]
    assert leg.loop.supervisor.phase_t_s == 0.0
    assert leg.sent("Set_Axis_State") == 2 and leg.sent("Set_Input_Pos") == 2 and leg.sent("Clear_Errors") == 0


def test_auto_arm_does_not_rearm_after_a_disarm():
    leg = Leg(auto_arm=True)
    for _ in range(100):
        leg.tick()
        leg.follow()
    assert leg.loop.phase is Phase.RAMP
    assert leg.loop.request_disarm(leg.t) is None
    for _ in range(500):
        leg.tick()
        leg.follow()
    assert leg.loop.phase is Phase.INACTIVE


def test_disarm_goes_back_to_inactive_with_the_axes_idle():
    leg = Leg()
    leg.tick()
    leg.loop.request_arm(leg.t)
    for _ in range(800):
        leg.tick()
        leg.follow()
    assert leg.loop.phase is Phase.WALK
    steps = len(leg.loop.stats.steps)
    n_pos = leg.sent("Set_Input_Pos")
    assert leg.loop.request_disarm(leg.t) is None
    assert leg.loop.phase is Phase.INACTIVE and leg.loop.supervisor.fault_cause == ""
    idle = C.codec("Set_Axis_State").pack(int(AxisState.IDLE))
    last = {m.arbitration_id: m.data for m in leg.bus.sent}
    assert all(last[C.odrive_id(n, "Set_Axis_State")] == idle for n in (0, 1))
    leg.follow()
    leg.tick(200)
    assert leg.loop.phase is Phase.INACTIVE and leg.sent("Set_Input_Pos") == n_pos  # no target after the disarm
    assert len(leg.loop.stats.steps) == steps and leg.sent("Clear_Errors") == 0
    assert all(s is AxisState.IDLE for s in leg.states.values())
    # a second disarm is refused; the leg arms again and walks
    assert "not armed" in leg.loop.request_disarm(leg.t)
    assert leg.loop.request_arm(leg.t) is None
    for _ in range(800):
        leg.tick()
        leg.follow()
    assert leg.loop.phase is Phase.WALK


def test_an_arm_is_refused_while_an_axis_is_not_idle_blocked_or_a_node_silent():
    leg = Leg()
    leg.tick(3)
    leg.states[0] = AxisState.CLOSED_LOOP_CONTROL  # someone left it armed
    leg.tick(1)
    assert "hip: CLOSED_LOOP_CONTROL" in leg.loop.request_arm(leg.t)
    leg.follow()  # INACTIVE sent it IDLE
    assert leg.states[0] is AxisState.IDLE and leg.sent("Set_Axis_State", 0) >= 1
    leg.tick(1)
    leg.loop.arm_blocked = "calibration not confirmed"
    assert leg.loop.request_arm(leg.t) == "calibration not confirmed"
    assert leg.loop.status()["arm_blocked"] == "calibration not confirmed"
    leg.loop.arm_blocked = None
    assert leg.loop.request_arm(leg.t) is None
    assert "only from inactive" in leg.loop.request_arm(leg.t)


def test_a_silent_node_in_inactive_is_a_fault():
    leg = Leg()
    leg.tick(3)
    assert leg.loop.phase is Phase.INACTIVE
    leg.quiet.add(1)
    leg.tick(300)
    assert leg.loop.phase is Phase.FAULT and "knee" in leg.loop.supervisor.fault_cause


def test_an_axis_error_while_arming_is_a_fault_named():
    leg = Leg()
    leg.tick(2)
    leg.loop.request_arm(leg.t)
    leg.errors[0] = int(AxisError.DRV_FAULT)
    leg.tick(2)
    assert leg.loop.phase is Phase.FAULT
    assert "hip" in leg.loop.supervisor.fault_cause and "DRV_FAULT" in leg.loop.supervisor.fault_cause


def test_estop_sends_estop_to_every_axis_and_latches_fault():
    leg = Leg()
    leg.tick(3)
    leg.loop.request_arm(leg.t)
    for _ in range(50):
        leg.tick()
        leg.follow()
    assert leg.loop.request_estop(leg.t) is None
    assert leg.sent("Estop", 0) == 1 and leg.sent("Estop", 1) == 1
    assert all(m.dlc == 0 for m in leg.bus.sent if (m.arbitration_id & 0x1F) == 0x002)
    assert leg.loop.phase is Phase.FAULT and leg.loop.supervisor.fault_cause == "estop by operator"
    assert leg.loop.lifecycle == "fault"
    leg.errors = {0: ESTOP, 1: ESTOP}
    leg.tick(500)
    assert leg.loop.phase is Phase.FAULT  # latched
    assert leg.loop.request_arm(leg.t) is not None
    assert leg.sent("Clear_Errors") == 0


def test_clear_faults_sends_clear_errors_and_leaves_fault_for_wait_nodes(caplog):
    leg = Leg()
    leg.tick(3)
    leg.loop.request_estop(leg.t)
    leg.errors = {0: ESTOP, 1: ESTOP}
    leg.tick(10)
    caplog.set_level(logging.WARNING, logger="controller.loop")
    assert leg.loop.request_clear_faults(leg.t) is None
    assert leg.sent("Clear_Errors", 0) == 1 and leg.sent("Clear_Errors", 1) == 1
    assert leg.loop.phase is Phase.WAIT_NODES and leg.loop.supervisor.fault_cause == ""
    assert sum("ESTOP_REQUESTED" in r.getMessage() and "Clear_Errors" in r.getMessage() for r in caplog.records) == 2
    leg.errors = {0: 0, 1: 0}  # the drivers cleared them
    leg.tick(2)
    assert leg.loop.phase is Phase.INACTIVE
    assert leg.loop.request_arm(leg.t) is None
    # refused while armed
    assert "disarm first" in leg.loop.request_clear_faults(leg.t)
    assert leg.sent("Clear_Errors") == 2


def test_clear_faults_waits_for_heartbeats_after_the_clearing():
    leg = Leg()
    leg.tick(3)
    leg.loop.request_estop(leg.t)
    leg.tick(1)
    leg.loop.request_clear_faults(leg.t - 1e-9)
    leg.tick(1, feedback=False)
    assert leg.loop.phase is Phase.WAIT_NODES  # the heartbeats it has are from before the clearing
    leg.tick(1)
    assert leg.loop.phase is Phase.INACTIVE


def test_another_master_is_a_fault_within_the_tick_that_drains_its_first_frame():
    for phase_ticks, arm in ((0, False), (3, False), (3, True)):
        leg = Leg()
        leg.tick(phase_ticks)
        if arm:
            leg.loop.request_arm(leg.t)
            leg.tick()
        rogue = C.odrive_id(0, "Set_Axis_State")
        leg.bus.push(data_frame(rogue, C.codec("Set_Axis_State").pack(int(AxisState.CLOSED_LOOP_CONTROL))),
                     data_frame(rogue, C.codec("Set_Axis_State").pack(int(AxisState.CLOSED_LOOP_CONTROL))))
        leg.tick()
        assert leg.loop.phase is Phase.FAULT, phase_ticks
        assert leg.loop.supervisor.fault_cause == "another master on the bus: id 0x007, 2 frame(s)"
        assert leg.loop.supervisor.fault_t_s == pytest.approx(leg.t - leg.loop.config.period_s)


def test_another_master_after_clearing_faults_again():
    leg = Leg()
    leg.tick(3)
    leg.bus.push(data_frame(C.odrive_id(1, "Estop"), b""))
    leg.tick()
    assert "id 0x022, 1 frame(s)" in leg.loop.supervisor.fault_cause
    leg.loop.request_clear_faults(leg.t)
    leg.tick(3)
    assert leg.loop.phase is Phase.INACTIVE  # the old frame is not counted again
    leg.bus.push(data_frame(C.odrive_id(0, "Set_Limits"), b"\x00" * 8))
    leg.tick()
    assert leg.loop.supervisor.fault_cause == "another master on the bus: id 0x00f, 1 frame(s)"


def test_status_is_json_serialisable_in_every_phase():
    leg = Leg()
    st = leg.loop.status()
    assert st["phase"] == "wait_nodes" and st["axes"]["hip"]["pos_rad"] is None and st["fault_t_s"] is None
    assert st["axes"]["hip"]["bus_voltage_v"] is None
    leg.bus.push(data_frame(C.odrive_id(0, "Get_Bus_Voltage_Current"),
                            C.codec("Get_Bus_Voltage_Current").pack(24.0, 0.5)))
    leg.tick(3)
    leg.loop.request_estop(leg.t)
    st = json.loads(json.dumps(leg.loop.status(), allow_nan=False))
    assert st["phase"] == "fault" and st["lifecycle"] == "fault" and st["fault_cause"] == "estop by operator"
    assert st["axes"]["hip"]["bus_voltage_v"] == pytest.approx(24.0) and st["axes"]["knee"]["bus_voltage_v"] is None
    assert st["axes"]["hip"]["state"] == "IDLE" and math.isfinite(st["axes"]["hip"]["pos_rad"])
    assert set(st) == {"phase", "lifecycle", "fault_cause", "fault_t_s", "axes", "ticks", "late_ticks",
                       "max_period_s", "steps", "reflexes", "arm_blocked"}


# --------------------------------------------------------------------------- the drivers' watchdog through SDO
def _sdo_sent(leg, node):
    out = []
    for m in leg.bus.sent:
        if m.arbitration_id == C.odrive_id(node, "RxSdo"):
            out.append(RXSDO.decode(m.data))
    return out


def test_arming_writes_the_drivers_watchdog_and_confirms_it_without_waiting():
    leg = Leg()
    leg.loop.drivers_watchdog_timeout_s = 0.25
    leg.tick(3)
    assert leg.loop.request_arm(leg.t) is None
    leg.tick()  # the arming frames: the write and the read go before the closed-loop request
    for node in (0, 1):
        ids = [m.arbitration_id for m in leg.bus.sent if m.arbitration_id >> 5 == node]
        assert ids.index(C.odrive_id(node, "RxSdo")) < ids.index(C.odrive_id(node, "Set_Axis_State"))
        write, read = _sdo_sent(leg, node)
        assert (write["Opcode"], write["Endpoint_ID"]) == (1, WATCHDOG_TIMEOUT.id)
        assert sdo_bits_value(int(write["Value"])) == pytest.approx(0.25)
        assert (read["Opcode"], read["Endpoint_ID"]) == (0, WATCHDOG_TIMEOUT.id)
    assert leg.loop.supervisor.pending_watchdog  # arming goes on before any reply
    for _ in range(800):
        leg.tick()
        leg.follow()
    assert leg.loop.phase is Phase.WALK and not leg.loop.supervisor.pending_watchdog
    assert leg.loop.io.rx["TxSdo"] == 2 and leg.loop.io.tx["RxSdo"] == 4
    assert all(len(_sdo_sent(leg, node)) == 2 for node in (0, 1))  # once per arming, not per retry


def test_a_driver_reading_back_another_watchdog_timeout_is_a_latched_fault(caplog):
    leg = Leg()
    leg.watchdog_reads[0] = 0.2  # the hip's driver answers 0.2 s whatever was written
    arm_and_run(leg, 300)
    sup = leg.loop.supervisor
    assert leg.loop.phase is Phase.FAULT
    assert sup.fault_cause == ("watchdog timeout not confirmed: hip wrote 0.1 s, read 0.2 s "
                               "(written and read again for 0.5 s)")
    leg.tick(100)
    assert leg.loop.phase is Phase.FAULT  # latched
    assert leg.sent("Set_Axis_State", 0) >= 2  # IDLE sent


@pytest.mark.parametrize("lost", [1, 2, 3])
def test_a_lost_write_or_read_is_sent_again_and_confirmed_without_a_fault(lost):
    """Frames get lost: a lost write reads back the old value, a lost read gets no reply; either
    way the controller writes and reads again until the values agree (within 0.5 s)."""
    leg = Leg()
    leg.lose_sdo[1] = lost  # 1: the write; 2: the write and the read; 3: the write, the read, the next write
    arm_and_run(leg, 400)
    assert leg.loop.phase is Phase.RAMP and not leg.loop.supervisor.pending_watchdog  # no fault
    assert len(_sdo_sent(leg, 1)) >= 4 and len(_sdo_sent(leg, 0)) == 2  # the knee's exchange again, the hip's once


def test_no_watchdog_read_back_within_half_a_second_is_a_fault_while_arming_goes_on():
    leg = Leg()
    leg.watchdog_reads[1] = "silent"
    leg.tick(3)
    leg.loop.request_arm(leg.t)
    t_arm = leg.t
    phases = set()
    while leg.loop.phase is not Phase.FAULT and leg.t < t_arm + 1.0:
        leg.tick()
        leg.follow()
        phases.add(leg.loop.phase)
    assert Phase.RAMP in phases  # arming did not wait for the reply
    assert leg.loop.supervisor.fault_cause == ("watchdog timeout not confirmed: knee wrote 0.1 s, "
                                               "no reply within 0.5 s")
    assert 0.5 < leg.loop.supervisor.fault_t_s - t_arm <= 0.51


def test_a_disarm_before_the_read_back_drops_the_expectation():
    leg = Leg()
    leg.watchdog_reads[0] = "silent"
    leg.tick(3)
    leg.loop.request_arm(leg.t)
    leg.tick()
    assert leg.loop.request_disarm(leg.t) is None
    leg.tick(400)
    assert leg.loop.phase is Phase.INACTIVE and not leg.loop.supervisor.pending_watchdog


def test_a_shin_brush_between_two_ticks_fires_a_reflex():
    """The board sends a contacts frame at each change: a shin that closes and opens again within
    one control period arrives as two frames drained in the same tick. The loop reads the
    switches' latch, so the reflex fires (it read only the last frame, and missed the brush)."""
    contacts = C.codec("SB_Contacts")
    frame_id = arbitration_id(SENSOR_BOARD_NODE_ID, contacts.cmd_id)
    leg = Leg()
    arm_and_run(leg, 800)
    assert leg.loop.phase is Phase.WALK and not leg.loop.stats.reflexes
    leg.bus.push(data_frame(frame_id, contacts.pack(0, 1, 0)), data_frame(frame_id, contacts.pack(0, 0, 1)))
    leg.tick()
    assert [r.cause for r in leg.loop.stats.reflexes] == ["shin"]
    leg.tick(5)
    assert len(leg.loop.stats.reflexes) == 1  # heard once


class _LongSwing:
    """A premotor that asks for a fixed burst and, unless None, its own longest burst."""

    def __init__(self, burst_s: float, longest_burst_s: float | None) -> None:
        self._burst_s = burst_s
        if longest_burst_s is not None:
            self.longest_burst_s = longest_burst_s

    def on_step_onset(self, now_s: float, cell: int | None, context: int | None = None) -> None:
        pass

    def burst_s(self, now_s: float) -> float:
        return self._burst_s

    def on_reflex(self, kind: str, now_s: float) -> None:
        pass

    def gated_weight(self) -> float:
        return 0.0


def test_a_premotor_that_declares_its_longest_burst_sets_the_cpgs_bound_and_no_other_does():
    config = ControllerConfig()
    assert config.cpg.burst_max_s == 0.6
    own = ControlLoop(config, FakeBus())  # the controller's own premotor: the configured bound
    assert own.cpg.set_burst_s(0.9) == 0.6
    plain = ControlLoop(config, FakeBus(), premotor=_LongSwing(0.9, None))
    assert plain.cpg.set_burst_s(plain.premotor.burst_s(0.0)) == 0.6
    longer = ControlLoop(config, FakeBus(), premotor=_LongSwing(0.9, 0.7))
    assert longer.cpg.set_burst_s(longer.premotor.burst_s(0.0)) == 0.7
    assert longer.cpg.set_burst_s(0.65) == 0.65 and longer.cpg.set_burst_s(0.05) == config.cpg.burst_min_s
    assert longer.config.cpg.burst_max_s == 0.6  # the configuration itself is not changed
    with pytest.raises(ValueError, match="burst_max_s"):  # shorter than the base burst: refused
        ControlLoop(config, FakeBus(), premotor=_LongSwing(0.3, 0.2))
