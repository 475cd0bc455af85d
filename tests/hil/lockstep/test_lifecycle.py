"""The lifecycle against the simulated leg in lockstep: the simulated ODrive axes latch an Estop,
arming never clears it, clearing the faults does; disarm, estop and a second master."""

from __future__ import annotations

from controller.supervisor import Phase
from hil.lockstep.harness import Lockstep, LockstepConfig
from protocol import AxisError, AxisState, BusContract, data_frame

C = BusContract.load()


def run_until(ls: Lockstep, t_s: float) -> None:
    while ls.t_s < t_s:
        ls.step()


def rx(ls: Lockstep, name: str) -> int:
    return sum(a.stats["rx"].get(name, 0) for a in ls.leg.axes.values())


def test_the_lockstep_arms_by_itself_and_manual_arming_is_possible():
    assert LockstepConfig().controller.auto_arm is True
    assert LockstepConfig(auto_arm=False).controller.auto_arm is False
    with Lockstep(LockstepConfig(seed=0, auto_arm=False)) as ls:
        run_until(ls, 1.0)
        assert ls.loop.phase is Phase.INACTIVE and ls.axes_idle()
        assert rx(ls, "Set_Axis_State") == 0


def test_a_latched_estop_refuses_the_arm_until_faults_are_cleared_then_disarm_and_estop():
    with Lockstep(LockstepConfig(seed=0, auto_arm=False)) as ls:
        hip = ls.leg.axes["hip"]
        hip.handle(data_frame(C.odrive_id(hip.node_id, "Estop"), b""), 0.0)  # latched before the controller starts
        run_until(ls, 0.5)
        assert ls.loop.phase is Phase.INACTIVE
        reason = ls.loop.request_arm(ls.t_s)
        assert reason is not None and "hip: ESTOP_REQUESTED (0x2000000)" in reason
        run_until(ls, 1.0)
        assert rx(ls, "Clear_Errors") == 0 and hip.errors & AxisError.ESTOP_REQUESTED
        assert ls.loop.request_clear_faults(ls.t_s) is None
        run_until(ls, 1.2)
        assert rx(ls, "Clear_Errors") == 2 and not hip.errors
        assert ls.loop.request_arm(ls.t_s) is None
        run_until(ls, 3.5)
        assert ls.loop.phase is Phase.WALK and rx(ls, "Clear_Errors") == 2
        assert ls.loop.request_disarm(ls.t_s) is None
        run_until(ls, 3.7)
        assert ls.loop.phase is Phase.INACTIVE and ls.axes_idle() and not hip.errors
        assert ls.loop.request_arm(ls.t_s) is None
        run_until(ls, 4.0)
        assert ls.loop.phase is Phase.RAMP
        assert ls.loop.request_estop(ls.t_s) is None
        run_until(ls, 4.2)
        assert ls.loop.phase is Phase.FAULT and ls.loop.supervisor.fault_cause == "estop by operator"
        assert ls.axes_idle() and all(a.errors & AxisError.ESTOP_REQUESTED for a in ls.leg.axes.values())


def test_a_second_master_is_a_latched_fault_in_the_tick_its_frame_is_drained():
    with Lockstep(LockstepConfig(seed=0)) as ls:
        run_until(ls, 3.0)
        assert ls.loop.phase is Phase.WALK
        rogue = ls.observer()
        try:
            rogue.send(data_frame(C.odrive_id(1, "Set_Axis_State"),
                                  C.codec("Set_Axis_State").pack(int(AxisState.CLOSED_LOOP_CONTROL))))
            while not ls.step():
                pass
            assert ls.loop.phase is Phase.FAULT
            assert ls.loop.supervisor.fault_cause == "another master on the bus: id 0x027, 1 frame(s)"
            run_until(ls, 3.2)
            assert ls.axes_idle()
        finally:
            rogue.shutdown()
