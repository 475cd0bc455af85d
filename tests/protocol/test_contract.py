"""The bus contract: the DBC's ODrive layouts, the compiled codecs against cantools, frame lengths."""

from __future__ import annotations

import math
import random
import struct

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


def _contract_of(signals: str, value_types: str = "") -> BusContract:
    import cantools

    text = ('VERSION ""\nNS_ :\nBS_:\nBU_: Controller ODrive\n\nBO_ 12 Set_Input_Pos: 8 Controller\n'
            f"{signals}\n{value_types}")
    return BusContract(cantools.database.load_string(text, strict=True))


@pytest.mark.parametrize("scale,offset", [(2, 0), (1, 1), (0.5, -3)])
def test_a_float_signal_with_a_scale_or_offset_is_read_as_cantools_reads_it(scale, offset):
    c = _contract_of(f' SG_ Input_Pos : 0|32@1+ ({scale},{offset}) [0|0] "rev" ODrive\n',
                     "SIG_VALTYPE_ 12 Input_Pos : 1;\n")
    codec = c.codec("Set_Input_Pos")
    assert not codec.compiled  # the struct path scales integers only
    for value in (1.25, -7.5, 0.0):
        data = codec.pack(value)
        assert data == bytes(codec.message.encode({"Input_Pos": value}))
        raw = struct.unpack("<f", data[:4])[0]
        assert raw == pytest.approx((value - offset) / scale)
        assert codec.unpack(data) == pytest.approx((value,)) and codec.decode(data) == pytest.approx(
            {"Input_Pos": value})
    unscaled = _contract_of(' SG_ Input_Pos : 0|32@1+ (1,0) [0|0] "rev" ODrive\n', "SIG_VALTYPE_ 12 Input_Pos : 1;\n")
    assert unscaled.codec("Set_Input_Pos").compiled


# --------------------------------------------------------------------------- a contract built inside the test
# (the module-level contract above is built at import: these build their own, so that every line of
# MessageCodec and BusContract runs under the test, as mutation testing needs)
def _sample(sig, k: int) -> float:
    """A value for ``sig``: for an integer signal a raw value inside its range (the k-th of a few)
    in physical units, for a float one a float32."""
    if sig.is_float:
        return [1.5, -2.25, 1e3][k % 3]
    lo, hi = (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed else (0, (1 << sig.length) - 1)
    raw = [hi, lo, min(hi, 3), max(lo, -3) if sig.is_signed else min(hi, 1)][k % 4]
    return raw * sig.scale + sig.offset


def test_a_fresh_contract_codes_every_message_exactly_as_cantools_does():
    import cantools

    from protocol import SHORT_FRAMES
    from protocol.contract import DBC_PATH

    db = cantools.database.load_file(str(DBC_PATH))
    c = BusContract(db)
    assert set(c.by_name) == {m.name for m in db.messages}
    assert c.master_messages == frozenset(m.name for m in db.messages if set(m.senders) == {"Controller"})
    assert c.odrive == {m.frame_id & 0x1F: c.codec(m.name) for m in db.messages if m.frame_id >> 5 == 0}
    assert c.sensor_board == {m.frame_id & 0x1F: c.codec(m.name) for m in db.messages if m.frame_id >> 5 == 16}
    for m in db.messages:
        codec = c.codec(m.name)
        signals = sorted(m.signals, key=lambda s: s.start)
        assert (codec.name, codec.frame_id, codec.cmd_id, codec.dlc) == (m.name, m.frame_id, m.frame_id & 0x1F, m.length)
        assert codec.min_length == min(SHORT_FRAMES.get(m.name, m.length), m.length)
        assert codec.signal_names == tuple(s.name for s in signals)
        for k in range(4):
            values = tuple(_sample(s, k) for s in signals)
            data = codec.pack(*values)
            assert data == bytes(m.encode(dict(zip(codec.signal_names, values)), scaling=True, strict=False)), m.name
            assert codec.encode(**dict(zip(codec.signal_names, values))) == data
            assert codec.unpack(data) == pytest.approx(values), m.name
            assert codec.decode(data) == pytest.approx(dict(zip(codec.signal_names, values)))
            assert codec.unpack(bytearray(data)) == pytest.approx(values)
        for i, s in enumerate(signals):  # one raw step beyond each integer signal's range is refused
            if s.is_float:
                continue
            lo, hi = (-(1 << (s.length - 1)), (1 << (s.length - 1)) - 1) if s.is_signed else (0, (1 << s.length) - 1)
            for raw in (hi + 1, lo - 1):
                values = [_sample(x, 0) for x in signals]
                values[i] = raw * s.scale + s.offset
                with pytest.raises(ValueError):
                    codec.pack(*values)
            values = [_sample(x, 0) for x in signals]
            values[i] = math.nan
            with pytest.raises(ValueError):
                codec.pack(*values)
        if signals:
            with pytest.raises(ValueError, match=rf"^{m.name} takes {len(signals)} signals, got {len(signals) + 1}$"):
                codec.pack(*([0] * (len(signals) + 1)))
            with pytest.raises(ValueError, match=rf"^{m.name}: .*{signals[-1].name}"):  # the missing one, by name
                codec.encode(**{s.name: _sample(s, 0) for s in signals[:-1]})


def test_an_int_for_an_unscaled_signal_packs_as_the_same_value_as_a_float():
    # pack's hot path takes an int for an unscaled integer signal as its raw value; a float (and
    # a bool) goes through (v - offset) / scale and round: both must give the same bytes and refuse
    # the same values.
    for codec in contract.by_name.values():
        if not codec.compiled or codec.message.signals == []:
            continue
        signals = sorted(codec.message.signals, key=lambda s: s.start)
        exact = [i for i, s in enumerate(signals) if not s.is_float and s.scale == 1 and s.offset == 0]
        for k in range(4):
            ints = [int(_sample(s, k)) if i in exact else _sample(s, k) for i, s in enumerate(signals)]
            floats = [float(v) if i in exact else v for i, v in enumerate(ints)]
            assert codec.pack(*ints) == codec.pack(*floats), codec.name
        for i in exact:
            s = signals[i]
            hi = (1 << (s.length - 1)) - 1 if s.is_signed else (1 << s.length) - 1
            for value in (hi + 1, float(hi + 1)):
                values = [_sample(x, 0) for x in signals]
                values[i] = value
                with pytest.raises(ValueError, match=rf"^{codec.name}: value {value!r} outside the signal's raw range"):
                    codec.pack(*values)
    assert contract.codec("SB_Contacts").pack(True, False, 7) == contract.codec("SB_Contacts").pack(1, 0, 7)


def test_pack_floats_is_pack_for_the_messages_of_floats_only():
    with_it = set()
    for codec in contract.by_name.values():
        signals = codec.message.signals
        if codec.pack_floats is None:
            assert not (codec.compiled and signals and all(s.is_float for s in signals)), codec.name
            continue
        with_it.add(codec.name)
        values = [(-1.0) ** k * (k + 0.1) for k in range(len(signals))]
        assert codec.pack_floats(*values) == codec.pack(*values), codec.name
    assert {"Get_Encoder_Estimates", "Set_Input_Vel", "Get_Iq"} <= with_it
    assert "Set_Input_Pos" not in with_it and "Heartbeat" not in with_it


def test_which_codecs_are_compiled_to_a_struct():
    import cantools

    from protocol.contract import DBC_PATH

    c = BusContract(cantools.database.load_file(str(DBC_PATH)))
    compiled = {name for name, codec in c.by_name.items() if codec.compiled}
    # every message whose signals are byte-aligned little-endian 8/16/32-bit fields, or floats
    assert compiled == set(c.by_name) - {"Heartbeat", "Address"}
    assert not c.codec("Heartbeat").compiled  # a 1-bit flag
    assert not c.codec("Address").compiled  # a 48-bit serial number


def test_short_payloads_read_as_zero_padded_down_to_their_minimum_and_no_further():
    import cantools

    from protocol.contract import DBC_PATH

    c = BusContract(cantools.database.load_file(str(DBC_PATH)))
    state = c.codec("Set_Axis_State")
    assert state.accepts_length(4) and not state.accepts_length(3) and state.accepts_length(8)
    assert state.unpack(b"\x08\x00\x00\x00") == (8,)
    with pytest.raises(ValueError, match=r"^Set_Axis_State: payload of 3 bytes, at least 4 expected$"):
        state.unpack(b"\x08\x00\x00")
    enc = c.codec("Get_Encoder_Estimates")
    with pytest.raises(ValueError, match=r"^Get_Encoder_Estimates: payload of 7 bytes, DLC 8 expected$"):
        enc.unpack(bytes(7))
    reboot = c.codec("Reboot")
    assert reboot.min_length == 0 and reboot.unpack(b"") == (0,)
    assert c.min_payload_length("RxSdo") == 4 and c.min_payload_length("Heartbeat") == 8


def test_cycle_times_ids_and_unknown_names():
    import cantools

    from protocol.contract import DBC_PATH

    c = BusContract(cantools.database.load_file(str(DBC_PATH)))
    assert c.cycle_time_s("Heartbeat") == 0.1 and c.cycle_time_s("Get_Encoder_Estimates") == 0.002
    assert c.cycle_time_s("SB_Contacts") == 0.005 and c.cycle_time_s("Set_Input_Pos") is None
    assert c.odrive_id(3, "Heartbeat") == 0x61
    with pytest.raises(KeyError, match="no message named 'Nope' in the DBC"):
        c.codec("Nope")
    assert arbitration_id(63, 31) == 0x7FF and arbitration_id(0, 0) == 0
    for bad in ((-1, 0), (64, 0), (0, -1), (0, 32)):
        with pytest.raises(ValueError, match="must be 0..63|must be 0..31"):
            arbitration_id(*bad)
    assert split_arbitration_id(0x7FF) == (63, 31)


def test_sdo_value_conversions_check_their_ranges():
    from protocol.contract import sdo_bits_value, sdo_value_bits

    assert sdo_bits_value(0) == 0.0 and sdo_bits_value(0xFFFFFFFF) != sdo_bits_value(0xFFFFFFFF)  # a NaN
    assert sdo_value_bits(1.0) == 0x3F800000 and sdo_bits_value(0x3F800000) == 1.0
    for bad in (-1, 1 << 32):
        with pytest.raises(ValueError, match=r"^SDO value bits must be a uint32, got "):
            sdo_bits_value(bad)
    with pytest.raises(ValueError, match=r"does not fit a float32 SDO value"):
        sdo_value_bits(1e39)
    with pytest.raises(ValueError):
        sdo_value_bits("x")  # type: ignore[arg-type]


def _contract_from(messages: str, value_types: str = "") -> BusContract:
    import cantools

    text = f'VERSION ""\nNS_ :\nBS_:\nBU_: Controller ODrive\n\n{messages}\n{value_types}'
    return BusContract(cantools.database.load_string(text, strict=True))


@pytest.mark.parametrize("signals,value_types", [
    # a gap between two fields, an offset integer, a non-byte-aligned float, a big-endian field
    (' SG_ A : 0|8@1+ (1,0) [0|0] "" ODrive\n SG_ B : 24|16@1- (1,0) [0|0] "" ODrive\n', ""),
    (' SG_ A : 0|16@1+ (1,-100) [0|0] "" ODrive\n SG_ B : 16|16@1- (0.5,3) [0|0] "" ODrive\n', ""),
    (' SG_ A : 1|32@1+ (1,0) [0|0] "" ODrive\n', "SIG_VALTYPE_ 12 A : 1;\n"),
    (' SG_ A : 7|16@0+ (1,0) [0|0] "" ODrive\n', ""),
], ids=["gap", "offset", "bit 1", "big endian"])
def test_other_layouts_are_coded_exactly_as_cantools_codes_them(signals, value_types):
    c = _contract_from(f"BO_ 12 Set_Input_Pos: 8 Controller\n{signals}", value_types)
    codec = c.codec("Set_Input_Pos")
    for k in range(4):
        values = tuple(_sample(s, k) for s in sorted(codec.message.signals, key=lambda s: s.start))
        data = codec.pack(*values)
        assert data == bytes(codec.message.encode(dict(zip(codec.signal_names, values)), strict=False))
        assert codec.unpack(data) == pytest.approx(values)
        assert codec.unpack(data) == pytest.approx(tuple(codec.message.decode(data)[n] for n in codec.signal_names))


def test_integers_of_an_unscaled_message_decode_as_ints_and_range_errors_say_why():
    import cantools

    from protocol.contract import DBC_PATH

    db = cantools.database.load_file(str(DBC_PATH))
    c = BusContract(db)
    assert c.db is db
    state = c.codec("Set_Axis_State")
    assert state.unpack(state.pack(8)) == (8,) and type(state.unpack(state.pack(8))[0]) is int
    limits = c.codec("Set_Controller_Mode")
    assert all(type(v) is int for v in limits.unpack(limits.pack(3, 1)))
    with pytest.raises(ValueError, match=r"^Set_Axis_State: value 4294967296 outside the signal's raw range "
                                         r"\(0, 4294967295\)$"):
        state.pack(1 << 32)
    with pytest.raises(ValueError, match=r"^Set_Axis_State: non-finite value nan for an integer signal$"):
        state.pack(math.nan)


def test_a_dbc_message_of_no_known_node_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"^DBC message Stray at 0x100 belongs to no known node$"):
        _contract_from('BO_ 256 Stray: 1 Controller\n SG_ X : 0|8@1+ (1,0) [0|0] "" ODrive\n')


# -- simulated time (hil --clock sim) ------------------------------------------------------------
def test_the_simulated_time_frames_are_extended_ids_of_no_node():
    from protocol.contract import CONTROLLER_STATE_ID, END_OF_PERIOD_ID, PHASE_CODES, SIM_SYNC_ID, SIM_TIME_IDS
    from controller.supervisor import Phase

    sync, eop = contract.codec("ES_Sim_Sync"), contract.codec("ES_End_Of_Period")
    state = contract.codec("ES_Controller_State")
    assert (sync.frame_id, eop.frame_id, state.frame_id) == (SIM_SYNC_ID, END_OF_PERIOD_ID, CONTROLLER_STATE_ID) \
        == (0x1FFFFF00, 0x1FFFFF01, 0x1FFFFF02)
    assert sync.message.is_extended_frame and eop.message.is_extended_frame and state.message.is_extended_frame
    assert contract.extended == {SIM_SYNC_ID: sync, END_OF_PERIOD_ID: eop, CONTROLLER_STATE_ID: state}
    assert SIM_TIME_IDS == set(contract.extended)
    # the state's codes: every phase, by the DBC's value table, in PHASE_CODES' order
    choices = state.message.get_signal_by_name("Phase").choices
    assert [str(choices[i]).lower() for i in range(len(choices))] == list(PHASE_CODES) == [p.value for p in Phase]
    assert state.message.senders == ["Controller"] and state.dlc == 1
    assert sync not in contract.odrive.values() and sync not in contract.sensor_board.values()
    assert eop not in contract.odrive.values() and eop not in contract.sensor_board.values()
    assert contract.route(SIM_SYNC_ID) is None and contract.route(END_OF_PERIOD_ID) is None
    assert contract.route(0x800) is None and contract.route(-1) is None
    # the plant side sends the sync, only the controller the end of period
    assert sync.message.senders == ["SensorBoard"] and "ES_Sim_Sync" not in contract.master_messages
    assert eop.message.senders == ["Controller"] and "ES_End_Of_Period" in contract.master_messages
    assert contract.odrive_master_cmds == frozenset({2, 4, 7, 11, 12, 13, 14, 15, 17, 18, 19, 22, 24, 25, 26, 27, 31})


def test_sim_time_crosses_the_bus_bit_for_bit():
    """The plant's clock is a sum of float steps (t += dt), which n * dt or whole microseconds
    do not reproduce: the frame carries the float64 itself."""
    t, dt, ts = 0.0, 1.0 / 1000.0, []
    for n in range(1, 3001):
        t += dt
        ts.append(t)
    assert any(t != n * dt for n, t in enumerate(ts, 1))  # why a float64 and not a count
    for name in ("ES_Sim_Sync", "ES_End_Of_Period"):
        codec = contract.codec(name)
        assert codec.compiled and codec.dlc == 8 and codec.signal_names == ("Sim_Time",)
        for t in (*ts[::97], 0.0, 1e9 + 1e-6, 2.0 ** -1074):
            data = codec.pack(t)
            assert data == struct.pack("<d", t) == bytes(codec.message.encode({"Sim_Time": t}))
            (back,) = codec.unpack(data)
            assert struct.pack("<d", back) == struct.pack("<d", t)


def test_exact_reader_decodes_every_message_as_unpack_does():
    """exact_reader (what BusIO.drain decodes with) is a bare struct read where that is exactly what unpack returns: for every
    message of the DBC and payloads of its DLC (random bytes: NaN, huge, negative values), the same
    tuple of the same types; Get_Encoder_Estimates (1,000 frames a second) takes the struct read."""
    rng = random.Random(3)
    fast = set()
    for name, codec in contract.by_name.items():
        read = codec.exact_reader()
        if read != codec.unpack:
            fast.add(name)
        for _ in range(500):
            data = bytearray(rng.getrandbits(8) for _ in range(codec.dlc))
            expected, got = codec.unpack(data), read(data)
            assert type(got) is type(expected) and len(got) == len(expected), name
            for e, g in zip(expected, got):
                assert type(g) is type(e) and (g == e or (e != e and g != g)), (name, bytes(data).hex())
    assert {"Get_Encoder_Estimates", "SB_Contacts", "Get_Iq", "Get_Temperature"} <= fast
    assert not {"Heartbeat", "SB_Range", "SB_Profile"} & fast  # scaled or bit fields: the codec


def test_unpack_scales_every_integer_signal_as_raw_times_scale_plus_offset_bit_for_bit():
    """The compiled scaling loop (C arithmetic on the raw int) gives the floats Python's
    ``raw * scale + offset`` gives, for random payloads of every compiled message with a scaled
    integer signal; unscaled signals come back as decoded (ints stay ints)."""
    rng = random.Random(5)
    checked = 0
    for codec in contract.by_name.values():
        signals = sorted(codec.message.signals, key=lambda s: s.start)
        if not codec.compiled or all(s.is_float or (s.scale == 1 and s.offset == 0) for s in signals):
            continue
        layout = struct.Struct(codec._struct.format)
        for _ in range(200):
            data = bytes(rng.getrandbits(8) for _ in range(codec.dlc))
            raw = layout.unpack_from(data)
            expected = tuple(r if s.is_float else r * float(s.scale) + float(s.offset) for r, s in zip(raw, signals))
            got = codec.unpack(data)
            assert [struct.pack("<d", v) if isinstance(v, float) else v for v in got] == \
                   [struct.pack("<d", v) if isinstance(v, float) else v for v in expected], codec.name
            assert [type(v) for v in got] == [type(v) for v in expected], codec.name
        checked += 1
    assert checked >= 3  # Set_Input_Pos, SB_Range, SB_Profile at least
