"""On-wire length of classic CAN frames (bit stuffing included) and bus load.

A classic data frame with an 11-bit id and ``n`` data bytes is, before stuffing,
SOF 1 + id 11 + RTR/IDE/r0 3 + DLC 4 + data 8n + CRC 15 (the stuffed region, 34 + 8n bits) +
CRC delimiter 1 + ACK 2 + EOF 7 + intermission 3 = 47 + 8n bits. An extended frame (CAN 2.0B,
a 29-bit id: DroneCAN's) is SOF 1 + base id 11 + SRR 1 + IDE 1 + id extension 18 + RTR 1 +
r1/r0 2 + DLC 4 + data 8n + CRC 15 (the stuffed region, 54 + 8n bits) + the same 13-bit tail =
67 + 8n bits. The transmitter inserts a complementary bit after five equal bits in the stuffed
region (stuff bits count towards the next run), so the worst case adds
floor((region - 1) / 4) bits: 135 bits for 8 bytes (160 extended).
:func:`frame_bits` computes the exact length of one frame (its CRC-15 included).
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = [
    "CRC15_POLY",
    "crc15",
    "frame_bits",
    "stuff_count",
    "worst_case_bits",
]

#: CAN CRC-15 generator x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1.
CRC15_POLY = 0x4599
_FIXED_TAIL = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, EOF, intermission


def crc15(bits: Iterable[int]) -> int:
    """CAN CRC-15 of a bit sequence (SOF through the data field), as the controller computes it."""
    crc = 0
    for bit in bits:
        nxt = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= CRC15_POLY
    return crc


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def stuff_count(bits: Iterable[int]) -> int:
    """Stuff bits a transmitter inserts into ``bits`` (after every run of five equal bits)."""
    count, run, last = 0, 0, -1
    for bit in bits:
        if bit == last:
            run += 1
        else:
            run, last = 1, bit
        if run == 5:
            count += 1
            last, run = 1 - bit, 1
    return count


def frame_bits(frame_id: int, data: bytes, extended: bool = False) -> int:
    """Exact bits on the wire of a classic data frame, intermission included: an 11-bit id, or
    with ``extended`` a 29-bit one."""
    if extended:
        if not 0 <= frame_id <= 0x1FFFFFFF:
            raise ValueError(f"frame_id must be a 29-bit identifier, got {frame_id:#x}")
    elif not 0 <= frame_id <= 0x7FF:
        raise ValueError(f"frame_id must be an 11-bit identifier, got {frame_id:#x}")
    if len(data) > 8:
        raise ValueError(f"a classic CAN frame carries at most 8 bytes, got {len(data)}")
    if extended:  # SOF, base id, SRR 1, IDE 1, id extension, RTR 0, r1 r0, DLC
        head = [0, *_bits(frame_id >> 18, 11), 1, 1, *_bits(frame_id & 0x3FFFF, 18), 0, 0, 0,
                *_bits(len(data), 4)]
    else:
        head = [0, *_bits(frame_id, 11), 0, 0, 0, *_bits(len(data), 4)]
    for byte in data:
        head += _bits(byte, 8)
    region = head + _bits(crc15(head), 15)
    return len(region) + stuff_count(region) + _FIXED_TAIL


def worst_case_bits(n_bytes: int = 8, extended: bool = False) -> int:
    """Upper bound of :func:`frame_bits` for ``n_bytes`` of data: 47 + 8n + floor((33 + 8n) / 4),
    or with ``extended`` 67 + 8n + floor((53 + 8n) / 4)."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"n_bytes must be in 0..8, got {n_bytes}")
    if extended:
        return 67 + 8 * n_bytes + (54 + 8 * n_bytes - 1) // 4
    return 47 + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4
