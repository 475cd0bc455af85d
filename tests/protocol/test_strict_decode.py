"""Every frame on the bus decodes against ODrive's own DBC (protocol/reference/), strictly.

A third node hears the whole bus during a 20 s lockstep walk and during a bring-up against the
simulated leg; each standard-id frame of an ODrive node N is decoded with cantools against the
reference's ``AxisN_`` message of its id in strict mode (a payload of another length than the
reference's DLC fails; cantools itself raises on a short one). Remote requests must carry the
reference's DLC. The sensor board's ``SB_`` frames (node 16, ours) and 29-bit ids are skipped and
counted.
"""

from __future__ import annotations

import uuid
from collections import Counter
from importlib import resources
from pathlib import Path

import can
import cantools
import pytest

from protocol import SENSOR_BOARD_NODE_ID, split_arbitration_id

REFERENCE_PATH = Path(str(resources.files("protocol").joinpath("reference", "odrive-cansimple-0.6.10.dbc")))
REFERENCE = cantools.database.load_file(str(REFERENCE_PATH))
REFERENCE_IDS = {m.frame_id: m for m in REFERENCE.messages}


class StrictTally:
    """Decodes every frame it is given against the reference and counts the outcome."""

    def __init__(self) -> None:
        self.decoded: Counter[str] = Counter()  # data frames, by reference message
        self.remote: Counter[str] = Counter()  # RTR requests, by reference message
        self.skipped: Counter[str] = Counter()  # "SB_", "extended", "error"
        self.failures: list[str] = []

    def add(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.skipped["error"] += 1
            return
        if msg.is_extended_id:
            self.skipped["extended"] += 1
            return
        node, _cmd = split_arbitration_id(msg.arbitration_id)
        if node == SENSOR_BOARD_NODE_ID:
            self.skipped["SB_"] += 1
            return
        ref = REFERENCE_IDS.get(msg.arbitration_id)
        data = bytes(msg.data)
        what = f"{msg.arbitration_id:#05x} {'RTR dlc ' + str(msg.dlc) if msg.is_remote_frame else data.hex() or '(empty)'}"
        if ref is None:
            self.failures.append(f"{what}: no message of the reference at this id")
            return
        if msg.is_remote_frame:
            if msg.dlc != ref.length:
                self.failures.append(f"{what}: RTR for {ref.name} with DLC {msg.dlc}, the reference's is {ref.length}")
            else:
                self.remote[ref.name] += 1
            return
        if len(data) != ref.length:
            self.failures.append(f"{what}: {ref.name} with {len(data)} bytes, the reference's DLC is {ref.length}")
            return
        try:
            REFERENCE.decode_message(msg.arbitration_id, data, decode_choices=True, scaling=True)
        except Exception as exc:  # noqa: BLE001 - any decode error is a failure to report
            self.failures.append(f"{what}: {ref.name} does not decode: {exc}")
            return
        self.decoded[ref.name] += 1

    def drain(self, bus: can.BusABC) -> None:
        while (msg := bus.recv(0)) is not None:
            self.add(msg)

    def summary(self) -> str:
        return (f"decoded {sum(self.decoded.values())} data frames, {sum(self.remote.values())} RTR; "
                f"skipped {dict(self.skipped)}; {len(self.failures)} failures")

    def check(self) -> None:
        shown = self.failures[:20] + ([f"... and {len(self.failures) - 20} more"] if len(self.failures) > 20 else [])
        assert not self.failures, self.summary() + "\n" + "\n".join(shown)


def _short_names(counter: Counter[str]) -> set[str]:
    return {name.split("_", 1)[1] for name in counter}


def test_the_tally_fails_a_short_set_axis_state_and_skips_ours():
    tally = StrictTally()
    tally.add(can.Message(arbitration_id=0x007, data=b"\x08\0\0\0", is_extended_id=False))  # ODrive's 4-byte example
    tally.add(can.Message(arbitration_id=0x027, data=b"\x08\0\0\0\0\0\0\0", is_extended_id=False))
    tally.add(can.Message(arbitration_id=0x208, data=bytes(4), is_extended_id=False))
    tally.add(can.Message(arbitration_id=0x1234567, data=bytes(8), is_extended_id=True))
    tally.add(can.Message(arbitration_id=0x029, is_remote_frame=True, dlc=8, is_extended_id=False))
    tally.add(can.Message(arbitration_id=0x009, is_remote_frame=True, dlc=0, is_extended_id=False))
    tally.add(can.Message(arbitration_id=0x008, data=bytes(8), is_extended_id=False))
    assert tally.decoded == {"Axis1_Set_Axis_State": 1} and tally.remote == {"Axis1_Get_Encoder_Estimates": 1}
    assert tally.skipped == {"SB_": 1, "extended": 1}
    assert len(tally.failures) == 3
    assert "4 bytes, the reference's DLC is 8" in tally.failures[0]


@pytest.mark.slow
def test_a_20_s_walk_decodes_strictly_against_odrive_s_dbc():
    from hil.lockstep.harness import Lockstep, LockstepConfig

    ls = Lockstep(LockstepConfig(seed=0))
    observer = ls.observer()
    tally = StrictTally()
    try:
        while ls.t_s < 20.0:
            ls.step()
            tally.drain(observer)
        tally.drain(observer)
    finally:
        observer.shutdown()
        ls.close()
    print(tally.summary())
    tally.check()
    # the walk really armed the leg and walked: states, setpoints and feedback were all heard
    assert {"Set_Axis_State", "Set_Controller_Mode", "Set_Input_Pos", "Heartbeat",
            "Get_Encoder_Estimates"} <= _short_names(tally.decoded)
    assert sum(tally.decoded.values()) > 20_000 and tally.skipped["SB_"] > 1_000


@pytest.mark.slow
def test_a_bring_up_decodes_strictly_against_odrive_s_dbc():
    from controller.bringup.checklist import Status
    from controller.bringup.procedure import run_bringup
    from controller.config import ControllerConfig
    from firmware_sim.leg import SimulatedLeg

    channel = f"strict-{uuid.uuid4().hex}"
    leg_bus = can.Bus(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    observer = can.Bus(interface="virtual", channel=channel)
    leg = SimulatedLeg(leg_bus, seed=0)
    tally = StrictTally()

    def sleep(dt_s: float) -> None:
        end = leg.t_s + dt_s - 1e-9
        while True:
            leg.step()
            tally.drain(observer)
            if leg.t_s >= end:
                return

    try:
        config = ControllerConfig()
        report = run_bringup(bus, config.axes, sensor_node_id=config.sensor_node_id, channel="virtual",
                             clock=lambda: leg.t_s, sleep=sleep)
        tally.drain(observer)
    finally:
        leg.close()
        for b in (leg_bus, bus, observer):
            b.shutdown()
    bad = [i.line() for i in report.checklist.items if i.status is not Status.PASS]
    assert report.passed, "\n".join(bad)
    print(tally.summary())
    tally.check()
    # bring-up asks (RTR), arms, moves and disarms: every kind of frame it uses was checked
    assert {"Get_Version", "Get_Error", "Get_Bus_Voltage_Current"} <= _short_names(tally.remote)
    assert {"Set_Axis_State", "Set_Input_Pos", "Heartbeat", "Get_Version"} <= _short_names(tally.decoded)
