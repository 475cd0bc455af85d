"""AxisLink's SDO frames (RxSdo write/read of an endpoint of protocol.endpoints) and TxSdo replies."""

from __future__ import annotations

import pytest

from controller.io.axis import AxisConfig, AxisLink
from protocol import BusContract
from protocol.contract import sdo_bits_value, sdo_value_bits
from protocol.endpoints import BY_PATH, ENABLE_WATCHDOG, WATCHDOG_TIMEOUT

C = BusContract.load()


def link(node=3):
    return AxisLink(AxisConfig("hip", node_id=node, min_rad=-1.0, max_rad=1.0), C)


def test_sdo_write_and_read_frames_follow_the_dbc():
    a = link()
    w = a.sdo_write_frame(WATCHDOG_TIMEOUT, 0.1)
    assert w.arbitration_id == C.odrive_id(3, "RxSdo") and len(w.data) == 8
    values = C.codec("RxSdo").decode(w.data)
    assert (values["Opcode"], values["Endpoint_ID"]) == (1, 200)
    assert sdo_bits_value(int(values["Value"])) == pytest.approx(0.1)
    assert C.codec("RxSdo").decode(a.sdo_write_frame(ENABLE_WATCHDOG, True).data)["Value"] == 1
    r = C.codec("RxSdo").decode(a.sdo_read_frame(WATCHDOG_TIMEOUT).data)
    assert (r["Opcode"], r["Endpoint_ID"], r["Value"]) == (0, 200, 0)


def test_txsdo_reply_is_kept_by_endpoint_with_its_time():
    a = link()
    assert a.sdo_reply(WATCHDOG_TIMEOUT) is None
    assert a.on_txsdo((0, WATCHDOG_TIMEOUT.id, 0, sdo_value_bits(0.2)), 1.0)
    assert a.sdo_reply(WATCHDOG_TIMEOUT) == pytest.approx(0.2)
    assert a.sdo_reply(WATCHDOG_TIMEOUT, since_s=1.5) is None  # older than asked
    assert a.on_txsdo((0, BY_PATH["axis0.controller.config.input_mode"].id, 0, 5), 2.0)
    assert a.sdo_reply(BY_PATH["axis0.controller.config.input_mode"]) == 5
    assert not a.on_txsdo((0, 0x1234, 0, 0), 2.0)  # an endpoint outside the table: invalid


def test_a_bool_endpoint_other_than_0_or_1_reads_as_an_error():
    a = link()
    a.on_txsdo((0, ENABLE_WATCHDOG.id, 0, 7), 0.0)
    with pytest.raises(ValueError):
        a.sdo_reply(ENABLE_WATCHDOG)
