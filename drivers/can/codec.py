"""Encode and decode the glider CAN profile ("raw" profile, ``glider.dbc``).

The DBC is the source of truth: frame layouts, scaling and physical ranges are read from it with
cantools. Each message is defined for node 0; node ``n`` (0..15) uses ``frame_id = base_id + n``
with every base id a multiple of 0x10, so the node id is the low nibble of the frame id.

Frames are packed here, not by cantools' per-call encode/decode: the profile's signals are all
Intel byte order (the DBC loader refuses others) in one 8-byte frame, so a frame is one 64-bit
little-endian integer and a signal a shifted bit field of it. Each message's fields (shift, mask,
sign, scale, offset, range) are laid out once at load; a frame then costs a few integer
operations per signal (``python -m bench can``, *Codec cost per frame*, against cantools on the
same payloads). The raw value is cantools' own, ``round((value - offset) / scale)``, and the
physical value ``raw * scale + offset``, so both agree with cantools bit for bit (tested).

Contracts:

1. ``encode`` takes physical values (SI units, radians); every signal is needed except the
   lockstep signals added in profile revision 2 (:data:`OPTIONAL_SIGNALS`, 0 when left out,
   which is what a revision-1 sender's unused bits say). A value outside the signal's DBC
   ``[min|max]`` (including ``±inf``) is clamped to the nearer limit and counted per signal in
   the ``tx`` saturation counters; it never wraps. NaN is refused with ``ValueError``.
   Angle signals (``heading_rad``, ``nb_heading_rad``) are first normalised to ``[-pi, pi)``.
   Rolling counters (:data:`COUNTER_SIGNALS`) are sequence numbers, not physical values: any
   integer is taken modulo the field's width (a frame whose field is narrower than the counter,
   as GLIDER_STATE_QUAT's one-bit ``state_counter``, carries its low bits); a non-integer is
   refused with ``ValueError``.
2. ``decode`` takes a received frame and returns physical values. A raw value that decodes
   outside ``[min|max]`` (the field has spare codes beyond the range) is clamped and counted in
   the ``rx`` saturation counters.
3. A frame that is not part of the profile (extended/remote/error/FD frame, unknown base id,
   wrong length) raises :class:`hil_bridge.errors.CodecError`; callers drop and count it.
4. Counters are thread-safe; one codec may serve a receive and a transmit thread.
"""

from __future__ import annotations

import math
import threading
from collections import Counter
from collections.abc import Iterable, Mapping
from copy import deepcopy
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
from cantools.database.can import Database, Signal
from cantools.database.can import Message as DbcMessage

from hil_bridge.errors import CodecError

__all__ = [
    "ANGLE_SIGNALS",
    "COUNTER_SIGNALS",
    "DBC_PATH",
    "MAX_NODE_ID",
    "OPTIONAL_SIGNALS",
    "DecodedFrame",
    "GliderCanCodec",
    "SignalSpec",
    "load_database",
    "node_database",
]

#: The profile's DBC (installed with the package).
DBC_PATH = Path(__file__).resolve().with_name("glider.dbc")
#: Node ids run 0..MAX_NODE_ID (the low nibble of the frame id).
MAX_NODE_ID = 15
#: Signals that are angles and are normalised to [-pi, pi) before encoding.
ANGLE_SIGNALS = frozenset({"heading_rad", "nb_heading_rad"})

#: Rolling counters: taken modulo their field width on encode, never saturated.
COUNTER_SIGNALS = frozenset(
    {"state_counter", "cmd_counter", "answer_counter", "ap_counter", "bridge_counter", "nb_set"}
)

#: Signals of profile revision 2 (lockstep) that default to 0 when a caller leaves them out.
OPTIONAL_SIGNALS = frozenset({"lockstep", "answer", "answer_counter"})

_TWO_PI = 2.0 * math.pi


def node_database(nodes: Iterable[int], dbc_path: str | Path = DBC_PATH) -> Database:
    """The profile expanded for ``nodes``: every message once per node, named ``<NAME>_N<n>``
    with frame id ``base + n``, for vendor tools that look frames up by id (``candump | cantools
    decode``, PCAN-Explorer, SavvyCAN). Write it with ``.as_dbc_string()``."""
    base = load_database(dbc_path)
    messages = []
    for n in sorted(set(nodes)):
        _check_node_id(n)
        for msg in base.messages:
            copy = deepcopy(msg)
            copy.frame_id = msg.frame_id + n
            copy.name = f"{msg.name}_N{n}"
            messages.append(copy)
    return Database(messages=messages, nodes=base.nodes, version=base.version)


def load_database(path: str | Path = DBC_PATH) -> Database:
    """Load a DBC with cantools and check the profile's id rules (base ids multiples of 0x10)."""
    db = cantools.database.load_file(str(path), database_format="dbc")
    if not isinstance(db, Database):
        raise ValueError(f"{path}: not a CAN database")
    for msg in db.messages:
        if msg.is_extended_frame or msg.frame_id > 0x7FF:
            raise ValueError(f"{path}: message {msg.name} must use an 11-bit identifier")
        if msg.frame_id % 0x10:
            raise ValueError(
                f"{path}: message {msg.name} base id {msg.frame_id:#x} is not a multiple of 0x10"
            )
        if msg.length != 8:
            raise ValueError(f"{path}: message {msg.name} must be 8 bytes, not {msg.length}")
        for sig in msg.signals:
            if sig.byte_order != "little_endian" or sig.is_float or sig.is_multiplexer:
                raise ValueError(f"{path}: signal {msg.name}.{sig.name} must be an Intel "
                                 "(little-endian) integer signal")
    return db


@dataclass(frozen=True, slots=True)
class SignalSpec:
    """Physical range and resolution of one signal, as the DBC states them."""

    name: str
    minimum: float
    maximum: float
    scale: float
    bits: int
    signed: bool
    unit: str

    def clamp(self, value: float) -> float:
        """``value`` limited to the DBC range [minimum, maximum] (NaN passes through)."""
        return min(max(value, self.minimum), self.maximum)


@dataclass(frozen=True, slots=True)
class DecodedFrame:
    """One received profile frame: message name, node id and physical signal values."""

    name: str
    node_id: int
    signals: Mapping[str, float]


@dataclass(frozen=True, slots=True)
class _Field:
    """One signal as a bit field of the frame's 64-bit little-endian integer."""

    name: str
    shift: int
    mask: int
    #: 1 << (bits - 1) for a signed field (its sign bit), else 0
    sign: int
    scale: float
    offset: float
    minimum: float
    maximum: float
    counter: bool
    angle: bool
    optional: bool


@dataclass(frozen=True, slots=True)
class _MessageSpec:
    message: DbcMessage
    signals: tuple[SignalSpec, ...]
    fields: tuple[_Field, ...]
    names: frozenset[str]


def _field(msg: DbcMessage, sig: Signal, spec: SignalSpec, dbc_path: str | Path) -> _Field:
    """``sig`` (its range in ``spec``) laid out as a bit field; ``ValueError`` if its DBC range
    does not fit its bits."""
    bits = int(sig.length)
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if sig.is_signed else (0, (1 << bits) - 1)
    for limit in (spec.minimum, spec.maximum):
        raw = round((limit - sig.offset) / sig.scale)
        if not lo <= raw <= hi:
            raise ValueError(f"{dbc_path}: {msg.name}.{sig.name}: the range limit {limit} "
                             f"(raw {raw}) does not fit {bits} bits")
    return _Field(name=sig.name, shift=int(sig.start), mask=(1 << bits) - 1,
                  sign=(1 << (bits - 1)) if sig.is_signed else 0, scale=sig.scale,
                  offset=sig.offset, minimum=spec.minimum, maximum=spec.maximum,
                  counter=sig.name in COUNTER_SIGNALS, angle=sig.name in ANGLE_SIGNALS,
                  optional=sig.name in OPTIONAL_SIGNALS)


def _is_counter_field(sig: Signal) -> bool:
    return (not sig.is_signed and sig.scale == 1 and sig.offset == 0 and sig.minimum == 0
            and sig.maximum == (1 << sig.length) - 1)


def _normalise_angle(value: float) -> float:
    wrapped = (value + math.pi) % _TWO_PI - math.pi
    return -math.pi if wrapped >= math.pi else wrapped


class GliderCanCodec:
    """Codec of the glider profile (its DBC read by cantools) with node-id offsetting and
    saturation."""

    def __init__(self, dbc_path: str | Path = DBC_PATH) -> None:
        self.database = load_database(dbc_path)
        self._by_name: dict[str, _MessageSpec] = {}
        self._by_base: dict[int, _MessageSpec] = {}
        for msg in self.database.messages:
            specs = []
            for sig in msg.signals:
                if sig.minimum is None or sig.maximum is None:
                    raise ValueError(f"{dbc_path}: signal {sig.name} needs a [min|max] range")
                if sig.name in COUNTER_SIGNALS and not _is_counter_field(sig):
                    raise ValueError(
                        f"{dbc_path}: {msg.name}.{sig.name} is a rolling counter: expected an "
                        f"unsigned field, scale 1, offset 0, range [0|2^bits-1]"
                    )
                specs.append(
                    SignalSpec(
                        name=sig.name,
                        minimum=float(sig.minimum),
                        maximum=float(sig.maximum),
                        scale=float(sig.scale),
                        bits=int(sig.length),
                        signed=bool(sig.is_signed),
                        unit=sig.unit or "",
                    )
                )
            fields = tuple(_field(msg, sig, spec, dbc_path)
                           for sig, spec in zip(msg.signals, specs, strict=True))
            entry = _MessageSpec(msg, tuple(specs), fields, frozenset(f.name for f in fields))
            self._by_name[msg.name] = entry
            self._by_base[msg.frame_id] = entry
        self._lock = threading.Lock()
        self._tx_saturated: Counter[str] = Counter()
        self._rx_saturated: Counter[str] = Counter()

    # -- lookup -------------------------------------------------------------------------------
    @property
    def message_names(self) -> tuple[str, ...]:
        return tuple(self._by_name)

    def signals(self, name: str) -> tuple[SignalSpec, ...]:
        """The signal specs of message ``name`` in DBC order."""
        return self._spec(name).signals

    def base_id(self, name: str) -> int:
        return int(self._spec(name).message.frame_id)

    def frame_id(self, name: str, node_id: int) -> int:
        """``base_id(name) + node_id``; ``node_id`` must be in 0..15."""
        _check_node_id(node_id)
        return self.base_id(name) + node_id

    def _spec(self, name: str) -> _MessageSpec:
        try:
            return self._by_name[name]
        except KeyError:
            raise ValueError(
                f"unknown CAN message {name!r}; expected one of {sorted(self._by_name)}"
            ) from None

    # -- encode -------------------------------------------------------------------------------
    def encode_payload(self, name: str, values: Mapping[str, float]) -> bytes:
        """The 8 data bytes of message ``name`` for physical ``values`` (every signal needed)."""
        spec = self._spec(name)
        word = 0
        used = 0
        saturated: list[str] = []
        for f in spec.fields:
            try:
                raw = values[f.name]
                used += 1
            except KeyError:
                if not f.optional:
                    raise ValueError(f"{name}: missing value for signal {f.name!r}") from None
                continue  # 0 in its bits
            value = float(raw)
            if value != value:
                raise ValueError(f"{name}: signal {f.name!r} is NaN")
            if f.counter:
                if not value.is_integer():
                    raise ValueError(
                        f"{name}: counter {f.name!r} must be an integer, got {raw!r}"
                    )
                word |= (int(value) & f.mask) << f.shift
                continue
            if f.angle and math.isfinite(value):
                value = _normalise_angle(value)
            clamped = min(max(value, f.minimum), f.maximum)
            if clamped != value:
                saturated.append(f.name)
            word |= (round((clamped - f.offset) / f.scale) & f.mask) << f.shift
        if used != len(values):
            raise ValueError(f"{name}: unknown signal(s) {sorted(set(values) - spec.names)}")
        if saturated:
            with self._lock:
                self._tx_saturated.update(saturated)
        return word.to_bytes(8, "little")

    def encode(self, name: str, node_id: int, values: Mapping[str, float]) -> can.Message:
        """A python-can frame of message ``name`` for node ``node_id``."""
        return can.Message(
            arbitration_id=self.frame_id(name, node_id),
            is_extended_id=False,
            dlc=8,
            data=self.encode_payload(name, values),
        )

    # -- decode -------------------------------------------------------------------------------
    def decode(self, msg: can.Message) -> DecodedFrame:
        """Decode a received frame; raises :class:`CodecError` for a frame not in the profile."""
        if msg.is_error_frame:
            raise CodecError("error frame")
        if msg.is_remote_frame:
            raise CodecError(f"remote frame id {msg.arbitration_id:#x}")
        if msg.is_extended_id:
            raise CodecError(f"extended id {msg.arbitration_id:#x} is not in the profile")
        if msg.is_fd:
            raise CodecError(f"CAN FD frame id {msg.arbitration_id:#x} is not in the profile")
        return self.decode_payload(int(msg.arbitration_id), bytes(msg.data))

    def decode_payload(self, frame_id: int, data: bytes) -> DecodedFrame:
        """Decode ``data`` received with 11-bit ``frame_id``."""
        if not 0 <= frame_id <= 0x7FF:
            raise CodecError(f"frame id {frame_id:#x} is not an 11-bit identifier")
        spec = self._by_base.get(frame_id & ~0xF)
        if spec is None:
            raise CodecError(f"frame id {frame_id:#x} has no message in the profile")
        if len(data) != 8:
            raise CodecError(f"{spec.message.name}: length {len(data)}, expected 8")
        word = int.from_bytes(data, "little")
        signals: dict[str, float] = {}
        saturated: list[str] = []
        for f in spec.fields:
            raw = (word >> f.shift) & f.mask
            if raw & f.sign:
                raw -= f.mask + 1
            value = float(raw * f.scale + f.offset)
            clamped = min(max(value, f.minimum), f.maximum)
            signals[f.name] = clamped
            if clamped != value:
                saturated.append(f.name)
        if saturated:
            with self._lock:
                self._rx_saturated.update(saturated)
        return DecodedFrame(spec.message.name, frame_id & 0xF, signals)

    # -- counters -----------------------------------------------------------------------------
    def saturation_counts(self) -> dict[str, dict[str, int]]:
        """``{"tx": {signal: n}, "rx": {signal: n}}``: values clamped to the DBC range."""
        with self._lock:
            return {"tx": dict(self._tx_saturated), "rx": dict(self._rx_saturated)}

    @property
    def saturated_total(self) -> int:
        with self._lock:
            return sum(self._tx_saturated.values()) + sum(self._rx_saturated.values())


def _check_node_id(node_id: int) -> None:
    if isinstance(node_id, bool) or not isinstance(node_id, int):
        raise ValueError(f"node_id must be an int in 0..{MAX_NODE_ID}, got {node_id!r}")
    if not 0 <= node_id <= MAX_NODE_ID:
        raise ValueError(f"node_id must be in 0..{MAX_NODE_ID}, got {node_id}")
