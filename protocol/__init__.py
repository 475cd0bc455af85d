"""The bus contract shared by the controller and the simulated hardware.

One DBC file (``elegant_stepping.dbc``) is the single source of truth for every frame on the
bus: ODrive CANSimple (firmware 0.6.10, matched against ODrive's own DBC in ``reference/``) for
the motor drivers and our own sensor board.
This package loads it with cantools, compiles its byte-aligned layouts into precomputed
``struct`` codecs for the hot paths, names ODrive's enumerations, and computes bit-exact frame
lengths for bus-load figures.

May import: the standard library, numpy-free code only, ``cantools``. Never imports
``controller``, ``firmware_sim`` or ``hil``; both sides of the bus import this package.
"""

# first, before any hot module: ELEGANT_STEPPING_PURE_PYTHON=1 runs them as pure Python (protocol.compiled)
from protocol.compiled import install_pure_python_finder as _install_pure_python_finder

_install_pure_python_finder()

from protocol.contract import (
    SENSOR_BOARD_NODE_ID,
    SHORT_FRAMES,
    BusContract,
    MessageCodec,
    arbitration_id,
    sdo_bits_value,
    sdo_value_bits,
    split_arbitration_id,
)
from protocol.odrive import AxisError, AxisState, Cmd, ControlMode, InputMode, ProcedureResult, RebootAction, SdoOpcode
from protocol.frame import Frame, data_frame, remote_frame
from protocol.frame_bits import frame_bits

__all__ = [
    "BusContract",
    "MessageCodec",
    "SENSOR_BOARD_NODE_ID",
    "SHORT_FRAMES",
    "sdo_value_bits",
    "sdo_bits_value",
    "arbitration_id",
    "split_arbitration_id",
    "AxisError",
    "AxisState",
    "ControlMode",
    "InputMode",
    "ProcedureResult",
    "RebootAction",
    "SdoOpcode",
    "Cmd",
    "frame_bits",
    "Frame",
    "data_frame",
    "remote_frame",
]
