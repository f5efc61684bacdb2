"""Wire codec of the bus (``docs/spec/protocols.md`` §1, binding).

A message on the wire is three frames ``[topic, header, payload]``:

1. ``topic``: the UTF-8 topic name followed by one ``\\0`` byte (so a prefix subscription to
   ``/glider/1/state\\0`` never matches ``/glider/1/state_raw``).
2. ``header``: a msgpack map, keys in this order: ``type`` (str), ``v`` (int schema version),
   ``seq`` (uint, per publisher per topic, from 0), ``stamp_ns`` (int, sim time), ``pub_ns``
   (int, publisher's monotonic clock), ``frame_id`` (str), then the extension key ``src`` (str,
   the publisher's unique id: seq is counted per ``src``; readers that do not know it ignore it).
3. ``payload``: a msgpack map of the message's fields in declaration order. Arrays are maps
   ``{"dtype": "<f4", "shape": [n, ...], "data": <bin>}`` (little-endian, C order), never lists.

msgpack is written with ``use_bin_type=True`` and read with ``raw=False``. Decoding never trusts
the sender: an unknown type, a newer version than ours, a missing field or a malformed array
raises :class:`~hil_bridge.errors.CodecError` with the reason (receivers drop and count it).
Unknown payload keys (fields added by a newer sender of the same version) are ignored.
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from collections.abc import Sequence
from typing import Any

import msgpack
import numpy as np

from hil_bridge.bus.messages import Message, message_class
from hil_bridge.errors import CodecError

__all__ = [
    "HEADER_KEYS",
    "Envelope",
    "Header",
    "decode",
    "decode_header",
    "decode_payload",
    "decode_topic_header",
    "encode",
    "encode_header",
    "encode_payload",
    "pack_header",
    "payload_to_jsonable",
    "topic_frame",
    "topic_from_frame",
    "validate_topic",
]

#: Header keys of the spec, in wire order (``src`` is the echoloop extension, written last).
HEADER_KEYS = ("type", "v", "seq", "stamp_ns", "pub_ns", "frame_id")

_TOPIC_RE = re.compile(r"^(/[A-Za-z0-9_]+)+$")
_ARRAY_KEYS = frozenset(("dtype", "shape", "data"))
_ARRAY_KINDS = frozenset("biufc")
#: the dtype strings a receiver accepts: little-endian (or byte-order-free) numeric and bool.
#: Looked up, never parsed: ``np.dtype(str)`` evaluates comma strings with ``ast.literal_eval``.
_ARRAY_DTYPES: dict[str, np.dtype[Any]] = {
    d.str: d for d in (np.dtype(c).newbyteorder("<") for c in "?bBhHiIlLqQefdFD")
}
_FIELDS: dict[type[Message], tuple[str, ...]] = {}
_PLANS: dict[type[Message], tuple[tuple[str, bool, frozenset[type] | None, str], ...]] = {}
#: per class without array fields: its field names in wire order and each one's usual type
#: (float for a float field), or None; a payload that matches both is checked at once
_EXACT: dict[type[Message], tuple[tuple[str, ...], tuple[type, ...]] | None] = {}
#: topic frames seen, and their topics (validated); at most _TOPICS_MAX
_TOPICS: dict[bytes, str] = {}
_TOPICS_MAX = 4096
_SCALARS: dict[Any, tuple[type, ...]] = {
    int: (int,),
    float: (float, int),
    bool: (bool,),
    str: (str,),
}


def validate_topic(topic: str) -> str:
    """Return ``topic`` if it follows the ROS 2 grammar, else raise ``ValueError`` saying why.

    Grammar: characters ``[A-Za-z0-9_/]``, a leading ``/``, no ``//``, no trailing ``/``.
    """
    if not isinstance(topic, str):
        raise TypeError(f"topic must be a str, got {type(topic).__name__}")
    if not _TOPIC_RE.match(topic):
        raise ValueError(
            f"invalid topic {topic!r}: expected '/'-separated names of [A-Za-z0-9_], "
            "with a leading '/', no '//' and no trailing '/' (e.g. '/glider/0/state')"
        )
    return topic


def topic_frame(topic: str) -> bytes:
    """Frame 1 for ``topic``: UTF-8 name + ``\\0`` (validated)."""
    return validate_topic(topic).encode() + b"\0"


def topic_from_frame(frame: bytes) -> str:
    """Inverse of :func:`topic_frame`; ``CodecError`` if the frame is not a topic frame. A
    topic validated once is looked up after that (the first :data:`_TOPICS_MAX` topics)."""
    if type(frame) is not bytes:  # a buffer that may change or not hash
        frame = bytes(frame)
    topic = _TOPICS.get(frame)
    if topic is None:
        topic = _parse_topic_frame(frame)
        if len(_TOPICS) < _TOPICS_MAX:
            _TOPICS[frame] = topic
    return topic


def _parse_topic_frame(frame: bytes) -> str:
    if not frame.endswith(b"\0"):
        raise CodecError(f"topic frame {bytes(frame[:64])!r} does not end with a NUL byte")
    try:
        topic = bytes(frame[:-1]).decode()
        return validate_topic(topic)
    except (UnicodeDecodeError, ValueError) as exc:
        raise CodecError(f"bad topic frame {bytes(frame[:64])!r}: {exc}") from None


@dataclasses.dataclass(frozen=True, slots=True)
class Header:
    """Frame 2, decoded. ``src`` is empty when the sender does not write it."""

    type: str
    v: int
    seq: int
    stamp_ns: int
    pub_ns: int
    frame_id: str = ""
    src: str = ""


@dataclasses.dataclass(frozen=True, slots=True)
class Envelope:
    """One decoded bus message: topic, header, message, and the raw payload frame."""

    topic: str
    header: Header
    msg: Message
    payload: bytes


def _fields(cls: type[Message]) -> tuple[str, ...]:
    names = _FIELDS.get(cls)
    if names is None:
        names = tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]
        _FIELDS[cls] = names
    return names


def _plan(cls: type[Message]) -> tuple[tuple[str, bool, frozenset[type] | None, str], ...]:
    """Per field of ``cls``: its name, whether it is an array map, the exact Python types
    msgpack may decode it to (None: unchecked) and the name of the type expected. msgpack
    yields built-in types only, so an exact type test is the ``isinstance`` test it replaces
    (bool is not an int here), at less cost."""
    plan = _PLANS.get(cls)
    if plan is None:
        hints = typing.get_type_hints(cls)
        rows = []
        for name in _fields(cls):
            hint = hints[name]
            types: tuple[type, ...] | None = None
            if hint in _SCALARS:
                types = _SCALARS[hint]
            elif typing.get_origin(hint) is dict:
                types = (dict,)
            rows.append((name, name in cls.ARRAYS, None if types is None else frozenset(types),
                         "" if types is None else types[0].__name__))
        exact = all(not is_array and allowed is not None for _, is_array, allowed, _ in rows)
        # before the plan: a thread that finds the plan finds this too
        _EXACT[cls] = ((tuple(r[0] for r in rows),
                        tuple(_SCALARS.get(hints[r[0]], (dict,))[0] for r in rows))
                       if exact else None)
        plan = _PLANS[cls] = tuple(rows)
    return plan


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return _array_map(obj)
    raise TypeError(f"cannot encode {type(obj).__name__} value {obj!r} on the bus")


def _array_map(arr: np.ndarray) -> dict[str, Any]:
    if arr.dtype.kind not in _ARRAY_KINDS:
        raise CodecError(f"cannot encode array of dtype {arr.dtype}; numeric or bool only")
    le = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
    return {"dtype": le.dtype.str, "shape": list(le.shape), "data": le.tobytes()}


def _array_from_map(name: str, value: Any) -> np.ndarray:
    if not isinstance(value, dict) or value.keys() != _ARRAY_KEYS:
        raise CodecError(f"field {name!r}: expected an array map {{dtype, shape, data}}")
    dtype = _ARRAY_DTYPES.get(value["dtype"]) if isinstance(value["dtype"], str) else None
    if dtype is None:
        raise CodecError(
            f"field {name!r}: bad array map: unknown dtype {value['dtype']!r}; expected one of "
            f"{sorted(_ARRAY_DTYPES)}"
        )
    shape = value["shape"]
    data = value["data"]
    if (
        not isinstance(shape, list)
        or not all(isinstance(s, int) and s >= 0 for s in shape)
        or not isinstance(data, bytes)
    ):
        raise CodecError(
            f"field {name!r}: bad array map (dtype {value['dtype']!r}, shape {shape!r}); "
            "expected a little-endian numeric dtype, a list of sizes and bin data"
        )
    expected = math.prod(shape) * dtype.itemsize
    if len(data) != expected:
        raise CodecError(
            f"field {name!r}: array data has {len(data)} bytes, shape {shape} of {dtype.str} "
            f"needs {expected}"
        )
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def encode_payload(msg: Message) -> bytes:
    """Frame 3: the message's fields as a msgpack map (arrays as dtype/shape/bin maps)."""
    cls = type(msg)
    arrays = cls.ARRAYS
    body = {
        name: (_array_map(getattr(msg, name)) if name in arrays else getattr(msg, name))
        for name in _fields(cls)
    }
    try:
        return msgpack.packb(body, use_bin_type=True, default=_default)
    except (TypeError, ValueError, OverflowError) as exc:
        raise CodecError(f"cannot encode {cls.TYPE}: {exc}") from None


def encode_header(
    msg: Message, *, seq: int, pub_ns: int, frame_id: str = "", src: str = ""
) -> bytes:
    """Frame 2 for ``msg`` (``stamp_ns`` is the message's own)."""
    return pack_header(
        Header(msg.TYPE, msg.VERSION, seq, int(msg.stamp_ns), pub_ns, frame_id, src)  # type: ignore[attr-defined]
    )


def pack_header(header: Header) -> bytes:
    """Frame 2 from a :class:`Header` (keys in wire order); used to re-send recorded messages."""
    return msgpack.packb(
        {
            "type": header.type,
            "v": header.v,
            "seq": header.seq,
            "stamp_ns": header.stamp_ns,
            "pub_ns": header.pub_ns,
            "frame_id": header.frame_id,
            "src": header.src,
        },
        use_bin_type=True,
    )


def encode(
    topic: str, msg: Message, *, seq: int, pub_ns: int, frame_id: str = "", src: str = ""
) -> list[bytes]:
    """The three frames of ``msg`` on ``topic``."""
    if not isinstance(msg, Message) or not msg.TYPE:
        raise TypeError(f"expected a registered hil_bridge message, got {type(msg).__name__}")
    return [
        topic_frame(topic),
        encode_header(msg, seq=seq, pub_ns=pub_ns, frame_id=frame_id, src=src),
        encode_payload(msg),
    ]


def decode_header(frame: bytes) -> Header:
    """Frame 2 → :class:`Header`; ``CodecError`` if a key is missing or of the wrong type."""
    try:
        h = msgpack.unpackb(frame, raw=False)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise CodecError(f"header is not valid msgpack: {exc}") from None
    if not isinstance(h, dict):
        raise CodecError(f"header must be a msgpack map, got {type(h).__name__}")
    try:
        type_, v, seq, stamp_ns, pub_ns = h["type"], h["v"], h["seq"], h["stamp_ns"], h["pub_ns"]
    except KeyError as exc:
        raise CodecError(f"header misses key {exc.args[0]!r}; expected {HEADER_KEYS}") from None
    frame_id = h.get("frame_id", "")
    src = h.get("src", "")
    # exact types (a bool is not a number here); cheaper than isinstance on the hot path
    if not (
        type(type_) is str and type(v) is int and type(seq) is int
        and type(stamp_ns) is int and type(pub_ns) is int
        and type(frame_id) is str and type(src) is str
    ):
        raise CodecError(f"header has a value of the wrong type: {h!r}")
    return Header(type_, v, seq, stamp_ns, pub_ns, frame_id, src)


def decode_payload(type_name: str, version: int, frame: bytes) -> Message:
    """Frame 3 → message of ``type_name``; ``CodecError`` if unknown, newer, or malformed."""
    cls = message_class(type_name)
    if version > cls.VERSION:
        raise CodecError(
            f"{type_name} version {version} is newer than this build's {cls.VERSION}; "
            "upgrade echoloop on the receiving side"
        )
    try:
        body = msgpack.unpackb(frame, raw=False)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise CodecError(f"{type_name} payload is not valid msgpack: {exc}") from None
    if not isinstance(body, dict):
        raise CodecError(f"{type_name} payload must be a msgpack map, got {type(body).__name__}")
    plan = _plan(cls)
    exact = _EXACT[cls]
    if (exact is not None and tuple(body) == exact[0]
            and tuple(map(type, body.values())) == exact[1]):
        kwargs: dict[str, Any] = body  # every field, each of its usual type, in wire order
    else:
        kwargs = _checked(type_name, plan, body)
    try:
        return cls(**kwargs)
    except Exception as exc:  # any constructor check failing means the frame is bad
        raise CodecError(f"{type_name} payload does not fit the message: {exc}") from None


def _checked(
    type_name: str, plan: tuple[tuple[str, bool, frozenset[type] | None, str], ...],
    body: dict[str, Any],
) -> dict[str, Any]:
    """The constructor's arguments from ``body``, field by field: arrays rebuilt, scalars of
    an allowed type, keys of no field left out; ``CodecError`` naming a bad field."""
    kwargs: dict[str, Any] = {}
    for name, is_array, allowed, expected in plan:
        if name in body:
            value = body[name]
            if is_array:
                value = _array_from_map(name, value)
            elif allowed is not None and type(value) not in allowed:
                raise CodecError(
                    f"{type_name}.{name}: expected {expected}, "
                    f"got {type(value).__name__} {value!r}"
                )
            kwargs[name] = value
    return kwargs


def decode_topic_header(frames: Sequence[bytes]) -> tuple[str, Header]:
    """Topic and header of a three-frame message, payload left undecoded (recorders, monitors);
    ``CodecError`` on any problem, including a foreign message with another frame count."""
    if len(frames) != 3:
        raise CodecError(f"expected 3 frames [topic, header, payload], got {len(frames)}")
    return topic_from_frame(frames[0]), decode_header(frames[1])


def decode(frames: Sequence[bytes]) -> Envelope:
    """Three frames → :class:`Envelope`; ``CodecError`` on any problem."""
    topic, header = decode_topic_header(frames)
    payload = bytes(frames[2])
    return Envelope(topic, header, decode_payload(header.type, header.v, payload), payload)


def payload_to_jsonable(msg: Message) -> dict[str, Any]:
    """The message's fields as JSON-ready values (arrays become nested lists; non-finite floats
    become ``None``), for ``topic echo`` and JSON export."""

    def conv(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return conv(v.tolist())
        if isinstance(v, np.generic):
            return conv(v.item())
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, list):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {str(k): conv(x) for k, x in v.items()}
        return v

    return {name: conv(getattr(msg, name)) for name in _fields(type(msg))}
