"""The CAN frame type both sides send: a ``can.Message`` that copies cheaply.

python-can's ``virtual`` bus deep-copies every frame once per receiver; ``can.Message``'s deep
copy goes through the generic ``copy`` machinery for its payload and dominated the lockstep
profile. :class:`Frame` is a ``can.Message`` in every respect, with a direct copy (a new
``bytearray`` for the payload). Real interfaces (SocketCAN) never copy and see no difference.

Compiled (:mod:`protocol.compiled`): :func:`data_frame` runs native; :class:`Frame` stays a Python
class (``@interpreted``): a native class cannot subclass ``can.Message``, and frames must be
``can.Message`` instances to every python-can bus.
"""

from __future__ import annotations

import can
import can.message  # noqa: F401 - compiled, the base class is read from its defining module, which must be imported

from protocol.compiled import interpreted

_new_object = object.__new__
"""``Frame.__new__`` (can.Message defines none), bound once: looked up through the class it costs
~0.1 us a frame on the hot path."""


@interpreted  # a can.Message subclass: a Python class even when compiled
class Frame(can.Message):
    __slots__ = ()

    def __deepcopy__(self, memo: dict | None) -> "Frame":
        new = _new_object(Frame)
        new.timestamp = self.timestamp
        new.arbitration_id = self.arbitration_id
        new.is_extended_id = self.is_extended_id
        new.is_remote_frame = self.is_remote_frame
        new.is_error_frame = self.is_error_frame
        new.channel = self.channel
        new.dlc = self.dlc
        new.data = bytearray(self.data)
        new.is_fd = self.is_fd
        new.is_rx = self.is_rx
        new.bitrate_switch = self.bitrate_switch
        new.error_state_indicator = self.error_state_indicator
        return new

    def __copy__(self) -> "Frame":
        """The same copy as :meth:`__deepcopy__` (a new payload; compiled, a class body cannot
        name its own methods, so this is a method of its own)."""
        return self.__deepcopy__(None)


def data_frame(arbitration_id: int, data: bytes | bytearray) -> Frame:
    """A standard-id classic data frame (built directly: this runs thousands of times a second).

    Hot path: :data:`_new_object` instead of ``Frame.__new__``, then every slot assigned once.
    """
    dlc = len(data)
    if not 0 <= arbitration_id <= 0x7FF or dlc > 8:
        raise ValueError(f"not a standard CAN frame: id {arbitration_id:#x}, {dlc} bytes")
    f = _new_object(Frame)
    f.timestamp = 0.0
    f.arbitration_id = arbitration_id
    f.is_extended_id = False
    f.is_remote_frame = False
    f.is_error_frame = False
    f.channel = None
    f.dlc = dlc
    f.data = bytearray(data)
    f.is_fd = False
    f.is_rx = True
    f.bitrate_switch = False
    f.error_state_indicator = False
    return f


def remote_frame(arbitration_id: int, dlc: int) -> Frame:
    """A standard-id remote request (RTR) for a message of length ``dlc``."""
    return Frame(arbitration_id=arbitration_id, is_extended_id=False, is_remote_frame=True, dlc=dlc)
