"""Exact on-wire frame length: CRC-15, bit stuffing and the worst-case bound."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.busload import crc15, frame_bits, stuff_count, worst_case_bits


@pytest.mark.parametrize(
    ("bits", "stuffed"),
    [([0] * 4, 0), ([0] * 5, 1), ([1] * 10, 2), ([0] * 5 + [1] * 4, 2), ([0, 1] * 20, 0),
     ([0] * 5 + [1] * 3 + [0], 1)],
    ids=["four", "five", "ten", "stuff-bit-counts", "alternating", "run-broken"],
)
def test_stuff_count_hand_vectors(bits: list[int], stuffed: int) -> None:
    assert stuff_count(bits) == stuffed


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 1), min_size=1, max_size=120))
def test_crc_residue_is_zero(bits: list[int]) -> None:
    crc = crc15(bits)
    assert crc15(bits + [(crc >> (14 - i)) & 1 for i in range(15)]) == 0


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_frame_bits_within_bounds(frame_id: int, data: bytes) -> None:
    n = len(data)
    assert 47 + 8 * n <= frame_bits(frame_id, data) <= worst_case_bits(n)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 0x1FFFFFFF), st.binary(min_size=0, max_size=8))
def test_extended_frame_bits_within_bounds(frame_id: int, data: bytes) -> None:
    n = len(data)
    assert 67 + 8 * n <= frame_bits(frame_id, data, extended=True) <= worst_case_bits(n, True)


def test_extended_worst_case_values() -> None:
    assert worst_case_bits(8, True) == 160 and worst_case_bits(0, True) == 80
    # an all-ones id and payload: long runs, close to the bound
    assert frame_bits(0x1FFFFFFF, b"\xff" * 8, extended=True) >= 145
    with pytest.raises(ValueError, match="29-bit"):
        frame_bits(0x20000000, b"", extended=True)


def test_worst_case_values() -> None:
    assert worst_case_bits(8) == 135 and worst_case_bits(0) == 55
    # all-ones payload after an all-ones id: long runs, close to the bound
    assert frame_bits(0x7FF, b"\xff" * 8) > 125
    with pytest.raises(ValueError, match="11-bit"):
        frame_bits(0x800, b"")
    with pytest.raises(ValueError, match="at most 8"):
        frame_bits(0x100, bytes(9))
