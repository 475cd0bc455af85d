"""Our DBC against ODrive's own DBC for firmware 0.6.10 (protocol/reference/), field by field.

Every ODrive message of axis 0 in the reference must be in ``elegant_stepping.dbc`` under ODrive's
name without the ``Axis0_`` prefix, with the same id, DLC, senders (``Master`` is our
``Controller``, ``ODrive_Axis0`` our ``ODrive``) and, signal by signal, the same name, start bit,
length, byte order, sign, float type, scale, offset, multiplexer flag and value table. Each
difference is one line of the failure message. The enums of :mod:`protocol.odrive` must agree with
the value tables; the short-frame and SDO helpers of :mod:`protocol.contract` are checked here too.
"""

from __future__ import annotations

import hashlib
import math
import re
import struct
import sys
from importlib import resources
from pathlib import Path

import cantools
import pytest

from protocol import (
    SHORT_FRAMES,
    AxisError,
    AxisState,
    BusContract,
    Cmd,
    ControlMode,
    InputMode,
    ProcedureResult,
    RebootAction,
    SdoOpcode,
    sdo_bits_value,
    sdo_value_bits,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[2]
REFERENCE_PATH = Path(str(resources.files("protocol").joinpath("reference", "odrive-cansimple-0.6.10.dbc")))
REFERENCE_SHA256 = "b7fef5e257c1ce6e3095a57d9f999ed5d2004c9bb2b05aae4914378b2fbd4b5c"
NODES = {"Master": "Controller", "ODrive_Axis0": "ODrive"}  # the reference's node names -> ours

reference = cantools.database.load_file(str(REFERENCE_PATH))
contract = BusContract.load()
ours = contract.db
AXIS0 = sorted((m for m in reference.messages if m.name.startswith("Axis0_")), key=lambda m: m.frame_id)


def _choices(sig) -> dict[int, str] | None:
    return None if not sig.choices else {int(k): str(v) for k, v in sig.choices.items()}


def differences(ref: cantools.database.Message) -> list[str]:
    """Every way our DBC's message differs from the reference's axis-0 message ``ref``, one line each."""
    name = ref.name.removeprefix("Axis0_")
    try:
        msg = ours.get_message_by_name(name)
    except KeyError:
        return [f"{name}: missing from our DBC (reference {ref.name} at {ref.frame_id:#05x})"]
    out = []

    def diff(what: str, theirs, mine) -> None:
        if theirs != mine:
            out.append(f"{name}: {what} is {mine!r}, the reference's is {theirs!r}")

    diff("frame id", ref.frame_id, msg.frame_id)
    diff("extended id", ref.is_extended_frame, msg.is_extended_frame)
    diff("DLC", ref.length, msg.length)
    diff("senders", sorted(NODES.get(s, s) for s in ref.senders), sorted(msg.senders))
    theirs = {s.name: s for s in ref.signals}
    mine = {s.name: s for s in msg.signals}
    for missing in sorted(theirs.keys() - mine.keys()):
        out.append(f"{name}: signal {missing} missing")
    for extra in sorted(mine.keys() - theirs.keys()):
        out.append(f"{name}: signal {extra} is not in the reference")
    for sig_name in sorted(theirs.keys() & mine.keys()):
        t, m = theirs[sig_name], mine[sig_name]
        for field in ("start", "length", "byte_order", "is_signed", "is_float", "scale", "offset", "is_multiplexer",
                      "multiplexer_ids", "multiplexer_signal"):
            diff(f"{sig_name}.{field}", getattr(t, field), getattr(m, field))
        diff(f"{sig_name} value table", _choices(t), _choices(m))
    return out


@pytest.mark.parametrize("ref", AXIS0, ids=[m.name for m in AXIS0])
def test_every_odrive_message_matches_the_reference(ref):
    diffs = differences(ref)
    assert not diffs, "\n".join(diffs)


def test_the_reference_is_odrive_s_file_unchanged():
    assert hashlib.sha256(REFERENCE_PATH.read_bytes()).hexdigest() == REFERENCE_SHA256
    assert reference.version == "0.6.10"
    assert len(AXIS0) == 28  # cmd ids 0x00-0x1F less 0x08, 0x0A, 0x10 and 0x1E, which ODrive leaves unused


def test_we_define_no_odrive_message_the_reference_lacks():
    names = {m.name.removeprefix("Axis0_") for m in AXIS0}
    odrive = [m.name for m in ours.messages if m.frame_id >> 5 == 0]
    assert sorted(set(odrive) - names) == []
    standard = [m for m in ours.messages if not m.is_extended_frame]
    assert all(m.name.startswith("SB_") and m.senders == ["SensorBoard"] for m in standard if m.frame_id >> 5)
    # the simulated-time frames: 29-bit ids, above every 11-bit id, and nothing else extended
    extended = {m.name: m.frame_id for m in ours.messages if m.is_extended_frame}
    assert extended == {"ES_Sim_Sync": 0x1FFFFF00, "ES_End_Of_Period": 0x1FFFFF01, "ES_Controller_State": 0x1FFFFF02}
    assert all(0x7FF < i <= 0x1FFFFFFF for i in extended.values())


@pytest.mark.parametrize("node", range(8))
def test_the_reference_places_node_n_at_n_shl_5(node):
    # Our DBC defines node 0 only and shifts by five for node N: the reference's AxisN_ say the same.
    for ref in AXIS0:
        other = reference.get_message_by_name(ref.name.replace("Axis0_", f"Axis{node}_"))
        assert other.frame_id == node << 5 | ref.frame_id and other.length == ref.length
        assert [(s.name, s.start, s.length, s.is_signed, s.is_float) for s in other.signals] == \
               [(s.name, s.start, s.length, s.is_signed, s.is_float) for s in ref.signals]


def test_cmd_ids_name_every_message():
    for ref in AXIS0:
        name = ref.name.removeprefix("Axis0_")
        assert Cmd[name.upper()] == ref.frame_id, name
    assert len(Cmd) == len(AXIS0)


def _table(message: str, signal: str) -> dict[int, str]:
    return _choices(ours.get_message_by_name(message).get_signal_by_name(signal))


@pytest.mark.parametrize("enum, message, signal", [
    (AxisState, "Heartbeat", "Axis_State"),
    (AxisState, "Set_Axis_State", "Axis_Requested_State"),
    (ProcedureResult, "Heartbeat", "Procedure_Result"),
    (AxisError, "Heartbeat", "Axis_Error"),
    (AxisError, "Get_Error", "Active_Errors"),
    (AxisError, "Get_Error", "Disarm_Reason"),
    (ControlMode, "Set_Controller_Mode", "Control_Mode"),
    (InputMode, "Set_Controller_Mode", "Input_Mode"),
    (RebootAction, "Reboot", "Action"),
    (SdoOpcode, "RxSdo", "Opcode"),
])
def test_enums_agree_with_the_value_tables(enum, message, signal):
    members = {int(e.value): e.name for e in enum.__members__.values()}
    table = {k: v.upper() for k, v in _table(message, signal).items()}
    assert members == table


def test_the_value_tables_odrive_names():
    assert _table("Heartbeat", "Axis_State")[5] == "SENSORLESS_CONTROL"
    assert _table("Set_Axis_State", "Axis_Requested_State")[14] == "ANTICOGGING_CALIBRATION"
    assert _table("Heartbeat", "Procedure_Result")[15] == "NOT_CONVERGING"
    assert ProcedureResult.NOT_CONVERGING == 15 and AxisState.SENSORLESS_CONTROL == 5
    assert AxisState.ANTICOGGING_CALIBRATION == 14


def test_no_code_names_the_old_procedure_result():
    hits = [str(p.relative_to(REPO)) for d in ("protocol", "controller", "firmware_sim", "hil", "tests", "docs")
            for p in (REPO / d).rglob("*") if p.suffix in (".py", ".dbc", ".md", ".toml")
            and p.name != "test_reference.py" and "NOT_CONVERGED" in p.read_text(errors="replace")]
    assert hits == []


def test_the_reference_is_never_loaded_at_run_time():
    pattern = re.compile(r"odrive-cansimple[-\w.]*\.dbc|[\"']reference[\"'/]")  # a file name or path in code
    hits = [str(p.relative_to(REPO)) for d in ("protocol", "controller", "firmware_sim", "hil")
            for p in (REPO / d).rglob("*.py") if pattern.search(p.read_text())]
    assert hits == []


def test_the_reference_ships_as_package_data():
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["protocol"]
    assert "*.dbc" in data and "reference/*.dbc" in data


# -- short frames --------------------------------------------------------------------------------
def test_short_frames_are_a_documented_few():
    assert dict(SHORT_FRAMES) == {"Set_Axis_State": 4, "RxSdo": 4, "Address": 0, "Clear_Errors": 0, "Reboot": 0}
    for name, codec in contract.by_name.items():
        assert codec.min_length == contract.min_payload_length(name) == SHORT_FRAMES.get(name, codec.dlc)
        assert codec.accepts_length(codec.dlc) and codec.accepts_length(codec.min_length)
        assert codec.min_length == 0 or not codec.accepts_length(codec.min_length - 1)


def test_a_four_byte_set_axis_state_reads_as_odrive_s_example_sends_it():
    codec = contract.codec("Set_Axis_State")
    assert codec.pack(AxisState.CLOSED_LOOP_CONTROL) == struct.pack("<I", 8) + bytes(4)  # we send the DBC's 8
    assert codec.unpack(struct.pack("<I", 8)) == (8,)  # ODrive's can_simple.py sends 4
    assert codec.unpack(bytearray(struct.pack("<I", 1)) + bytearray(4)) == (1,)
    with pytest.raises(ValueError, match="at least 4"):
        codec.unpack(b"\x08\x00\x00")


def test_other_messages_still_reject_short_payloads():
    for name in ("Set_Input_Pos", "Set_Input_Torque", "Set_Limits", "Heartbeat", "Set_Traj_Accel_Limits"):
        codec = contract.codec(name)
        with pytest.raises(ValueError, match=f"DLC {codec.dlc}"):
            codec.unpack(bytes(codec.dlc - 1))


def test_empty_reboot_clear_errors_and_address_read_as_zero():
    assert contract.codec("Reboot").unpack(b"") == (RebootAction.REBOOT,)
    assert contract.codec("Clear_Errors").unpack(b"") == (0,)
    assert contract.codec("Address").decode(b"") == {"Node_ID": 0, "Serial_Number": 0}


# -- the new messages' codecs --------------------------------------------------------------------
@pytest.mark.parametrize("value", [0.0, -0.0, 1.5, -2.25, 3.4e38, 1e-45, math.inf, -math.inf])
def test_sdo_float_values_round_trip_through_the_raw_uint32(value):
    bits = sdo_value_bits(value)
    assert 0 <= bits <= 0xFFFFFFFF and bits == struct.unpack("<I", struct.pack("<f", value))[0]
    assert sdo_bits_value(bits) == struct.unpack("<f", struct.pack("<f", value))[0]
    assert math.copysign(1.0, sdo_bits_value(bits)) == math.copysign(1.0, value)


def test_sdo_helpers_reject_what_no_float32_or_uint32_is():
    assert math.isnan(sdo_bits_value(sdo_value_bits(math.nan)))
    with pytest.raises(ValueError):
        sdo_value_bits(1e39)
    for bits in (-1, 1 << 32):
        with pytest.raises(ValueError):
            sdo_bits_value(bits)


def test_rx_and_tx_sdo_carry_odrive_s_endpoint_access_layout():
    rx, tx = contract.codec("RxSdo"), contract.codec("TxSdo")
    assert rx.compiled and tx.compiled
    endpoint = 0x1234
    write = rx.pack(SdoOpcode.WRITE, endpoint, 0, sdo_value_bits(2.5))
    assert write == struct.pack("<BHBf", 1, endpoint, 0, 2.5)  # ODrive's example: '<BHB' + 'f'
    assert write == rx.message.encode({"Opcode": 1, "Endpoint_ID": endpoint, "Reserved": 0,
                                       "Value": sdo_value_bits(2.5)})
    assert rx.unpack(struct.pack("<BHB", 0, endpoint, 0)) == (0, endpoint, 0, 0)  # a 4-byte read
    reply = struct.pack("<BHBI", 0, endpoint, 0, 123456)
    assert tx.decode(reply) == {"Reserved0": 0, "Endpoint_ID": endpoint, "Reserved1": 0, "Value": 123456}
    assert sdo_bits_value(tx.decode(struct.pack("<BHBf", 0, endpoint, 0, -7.0))["Value"]) == -7.0
    with pytest.raises(ValueError):
        tx.unpack(reply[:7])  # the ODrive always answers with 8


def test_address_traj_and_dfu_codecs():
    address = contract.codec("Address")
    assert not address.compiled  # the 48-bit serial number goes through cantools
    data = address.encode(Node_ID=3, Serial_Number=0x3987_3452_3130)
    assert data == bytes([3]) + (0x3987_3452_3130).to_bytes(6, "little") + b"\x00"
    assert address.decode(data) == {"Node_ID": 3, "Serial_Number": 0x3987_3452_3130}
    assert contract.codec("Set_Traj_Vel_Limit").pack(2.0) == struct.pack("<f", 2.0) + bytes(4)
    assert contract.codec("Set_Traj_Accel_Limits").pack(1.0, 3.0) == struct.pack("<ff", 1.0, 3.0)
    assert contract.codec("Set_Traj_Inertia").decode(struct.pack("<f", 0.5) + bytes(4)) == {"Traj_Inertia": 0.5}
    dfu = contract.codec("Enter_DFU_Mode")
    assert dfu.dlc == 0 and dfu.pack() == b"" and dfu.unpack(b"") == ()
