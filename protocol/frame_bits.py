"""Bit-exact length of a classic CAN 2.0 frame on the wire, including bit stuffing.

Bus load figures use this rather than a worst-case estimate: the stuffed region (SOF through
the CRC sequence) is built bit by bit, the CRC-15 computed, and a stuff bit counted after every
five equal bits. The fixed tail (CRC delimiter, ACK slot and delimiter, 7-bit EOF) and the
3-bit intermission are added unstuffed.
"""

from __future__ import annotations

_CRC15_POLY = 0x4599
_UNSTUFFED_TAIL_BITS = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, EOF, intermission


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def _crc15(bits: list[int]) -> int:
    crc = 0
    for bit in bits:
        crc_next = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if crc_next:
            crc ^= _CRC15_POLY
    return crc


def frame_bits(arbitration_id: int, data: bytes, *, extended: bool = False, remote: bool = False) -> int:
    """Number of bit times one frame occupies on the bus, stuff bits and intermission included.

    ``data`` is the payload (for a remote frame, pass ``bytes(dlc)``: its length sets the DLC
    and no data field is sent).
    """
    dlc = len(data)
    if dlc > 8:
        raise ValueError(f"classic CAN carries at most 8 data bytes, got {dlc}")
    bits = [0]  # SOF
    if extended:
        bits += _bits(arbitration_id >> 18, 11) + [1, 1] + _bits(arbitration_id & 0x3FFFF, 18)
        bits += [int(remote), 0, 0]  # RTR, r1, r0
    else:
        if arbitration_id > 0x7FF:
            raise ValueError(f"standard id out of range: {arbitration_id:#x}")
        bits += _bits(arbitration_id, 11) + [int(remote), 0, 0]  # RTR, IDE, r0
    bits += _bits(dlc, 4)
    if not remote:
        for byte in data:
            bits += _bits(byte, 8)
    bits += _bits(_crc15(bits), 15)
    stuffed = len(bits)
    run_bit, run_len = bits[0], 0
    for bit in bits:
        if bit == run_bit:
            run_len += 1
        else:
            run_bit, run_len = bit, 1
        if run_len == 5:
            stuffed += 1
            # the stuff bit is the complement and starts a new run of length 1
            run_bit, run_len = 1 - bit, 1
    return stuffed + _UNSTUFFED_TAIL_BITS
