"""The bus contract: the DBC's ODrive layouts, the compiled codecs against cantools, frame lengths."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import BusContract, Cmd, Frame, SENSOR_BOARD_NODE_ID, arbitration_id, frame_bits, split_arbitration_id

contract = BusContract.load()

# ODrive CANSimple (firmware 0.6.10): cmd id, DLC, and the signals' (start bit, length) as published
# (the whole contract against ODrive's own DBC: test_reference.py).
ODRIVE_LAYOUT = {
    "Heartbeat": (0x01, 8, {"Axis_Error": (0, 32), "Axis_State": (32, 8), "Procedure_Result": (40, 8)}),
    "Estop": (0x02, 0, {}),
    "Get_Error": (0x03, 8, {"Active_Errors": (0, 32), "Disarm_Reason": (32, 32)}),
    "Set_Axis_State": (0x07, 8, {"Axis_Requested_State": (0, 32)}),
    "Get_Encoder_Estimates": (0x09, 8, {"Pos_Estimate": (0, 32), "Vel_Estimate": (32, 32)}),
    "Set_Controller_Mode": (0x0B, 8, {"Control_Mode": (0, 32), "Input_Mode": (32, 32)}),
    "Set_Input_Pos": (0x0C, 8, {"Input_Pos": (0, 32), "Vel_FF": (32, 16), "Torque_FF": (48, 16)}),
    "Set_Input_Vel": (0x0D, 8, {"Input_Vel": (0, 32), "Input_Torque_FF": (32, 32)}),
    "Set_Input_Torque": (0x0E, 8, {"Input_Torque": (0, 32)}),
    "Set_Limits": (0x0F, 8, {"Velocity_Limit": (0, 32), "Current_Limit": (32, 32)}),
    "Get_Iq": (0x14, 8, {"Iq_Setpoint": (0, 32), "Iq_Measured": (32, 32)}),
    "Get_Bus_Voltage_Current": (0x17, 8, {"Bus_Voltage": (0, 32), "Bus_Current": (32, 32)}),
    "Clear_Errors": (0x18, 1, {"Identify": (0, 8)}),
    "Get_Torques": (0x1C, 8, {"Torque_Target": (0, 32), "Torque_Estimate": (32, 32)}),
}


@pytest.mark.parametrize("name", sorted(ODRIVE_LAYOUT))
def test_odrive_messages_follow_the_published_layout(name):
    cmd_id, dlc, signals = ODRIVE_LAYOUT[name]
    codec = contract.codec(name)
    assert codec.cmd_id == cmd_id == Cmd[name.upper()].value
    assert codec.dlc == dlc
    for sig in codec.message.signals:
        assert sig.byte_order == "little_endian"
        if sig.name in signals:
            assert (sig.start, sig.length) == signals[sig.name]
    assert set(signals) <= {s.name for s in codec.message.signals}


def test_float_signals_are_ieee754_floats():
    for name in ("Get_Encoder_Estimates", "Set_Input_Pos", "Get_Iq", "Get_Torques"):
        sig = contract.codec(name).message.signals[0]
        assert sig.is_float, f"{name}.{sig.name} must be a float32"


def test_arbitration_ids_are_node_shifted_by_five():
    assert arbitration_id(3, 0x0C) == 0x6C
    assert split_arbitration_id(0x6C) == (3, 0x0C)
    assert contract.odrive_id(1, "Heartbeat") == 0x21
    route = contract.route(0x6C)
    assert route is not None and route.node_id == 3 and route.codec.name == "Set_Input_Pos"
    assert contract.route(arbitration_id(SENSOR_BOARD_NODE_ID, 0x08)).codec.name == "SB_Range"
    assert contract.route(0x7FF).codec.name == "Enter_DFU_Mode"  # node 63, cmd 0x1F
    for unused in (0x08, 0x0A, 0x10, 0x1E):  # cmd ids ODrive leaves unused
        assert contract.route(arbitration_id(63, unused)) is None
    with pytest.raises(ValueError):
        arbitration_id(64, 1)


_values = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=32)


@settings(max_examples=200, deadline=None)
@given(pos=_values, vel_ff=st.floats(-32.0, 32.0), torque_ff=st.floats(-32.0, 32.0))
def test_compiled_codec_matches_cantools(pos, vel_ff, torque_ff):
    codec = contract.codec("Set_Input_Pos")
    assert codec.compiled
    ours = codec.pack(pos, vel_ff, torque_ff)
    reference = codec.message.encode({"Input_Pos": pos, "Vel_FF": vel_ff, "Torque_FF": torque_ff})
    assert ours == reference
    decoded = codec.unpack(ours)
    ref = codec.message.decode(reference)
    assert decoded[0] == pytest.approx(ref["Input_Pos"])
    assert decoded[1] == pytest.approx(ref["Vel_FF"]) and decoded[2] == pytest.approx(ref["Torque_FF"])


def test_heartbeat_uses_the_cantools_path_and_agrees():
    codec = contract.codec("Heartbeat")
    assert not codec.compiled  # the 1-bit trajectory flag is not byte-aligned
    data = codec.encode(Axis_Error=0x1000000, Axis_State=8, Procedure_Result=0, Trajectory_Done_Flag=1)
    assert data[:4] == (0x1000000).to_bytes(4, "little") and data[4] == 8 and data[6] & 1 == 1
    assert codec.unpack(data) == (0x1000000, 8, 0, 1)


def test_codec_rejects_short_payloads_and_out_of_range_integers():
    codec = contract.codec("Set_Input_Pos")
    with pytest.raises(ValueError):
        codec.unpack(b"\x00" * 7)
    with pytest.raises(ValueError):
        codec.pack(0.0, 40.0, 0.0)  # 40 rev/s does not fit an int16 at 0.001
    with pytest.raises(ValueError):
        codec.pack(0.0, math.nan, 0.0)


def test_frame_copies_are_independent_and_equal():
    import copy

    f = Frame(arbitration_id=0x0C, data=b"\x01\x02", is_extended_id=False)
    g = copy.deepcopy(f)
    assert isinstance(g, Frame) and g.equals(f)
    g.data[0] = 9
    assert f.data[0] == 1


def test_frame_bits_bounds_and_stuffing():
    # unstuffed length of a standard data frame: 44 + 8n bits + 3 intermission
    for n in range(9):
        bits = frame_bits(0x0C, bytes([0x5A] * n))
        assert 47 + 8 * n <= bits <= 47 + 8 * n + (34 + 8 * n - 1) // 4
    # all-zero payloads stuff far more than alternating ones
    assert frame_bits(0x00, bytes(8)) > frame_bits(0x155, bytes([0x55] * 8))
    assert frame_bits(0x09, bytes(8), remote=True) < frame_bits(0x09, bytes(8))
    with pytest.raises(ValueError):
        frame_bits(0x800, b"")


def test_the_contract_knows_what_only_the_master_sends():
    c = BusContract.load()
    assert c.odrive_master_cmds == frozenset({2, 4, 7, 11, 12, 13, 14, 15, 17, 18, 19, 22, 24, 25, 26, 27, 31})
    assert {"Set_Input_Pos", "Set_Axis_State", "Estop", "Clear_Errors", "RxSdo", "Enter_DFU_Mode"} <= c.master_messages
    assert not c.master_messages & {"Heartbeat", "Get_Encoder_Estimates", "SB_Range", "SB_Heartbeat", "TxSdo"}
    # Address is sent by the master and answered by the ODrive: hearing it proves no other master.
    assert "Address" not in c.master_messages and set(c.codec("Address").message.senders) == {"Controller", "ODrive"}
