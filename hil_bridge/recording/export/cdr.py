"""ROS 2 message definitions (``.msg``) shipped in ``hil_bridge/recording/export/msg`` and a CDR
encoder.

:func:`msgdef` gives the text rosbag2 embeds in a bag's schema (``ros2msg``: the type's
definition, then each dependency after a line of 80 ``=`` and ``MSG: pkg/Type``), and
:func:`encoder` a function turning a plain ``dict`` into the type's CDR bytes (little-endian,
XCDR1 ``CDR_LE`` encapsulation ``00 01 00 00``, each primitive aligned to its size from the
start of the payload). Missing fields take their zero value (or the ``.msg`` default); numeric
arrays may be numpy arrays (written in one block). Only the types shipped here are known.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["KNOWN_TYPES", "encoder", "msgdef"]

MSG_DIR = Path(__file__).with_name("msg")
_PRIMITIVES: dict[str, tuple[str, int]] = {
    "bool": ("?", 1), "byte": ("B", 1), "char": ("B", 1), "int8": ("b", 1), "uint8": ("B", 1),
    "int16": ("h", 2), "uint16": ("H", 2), "int32": ("i", 4), "uint32": ("I", 4),
    "int64": ("q", 8), "uint64": ("Q", 8), "float32": ("f", 4), "float64": ("d", 8),
}
_NUMPY = {"f": "<f4", "d": "<f8", "b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4",
          "I": "<u4", "q": "<i8", "Q": "<u8", "?": "?"}
_SEPARATOR = "=" * 80


@dataclass(frozen=True, slots=True)
class _Field:
    type: str  # a primitive, "string", or a full name "pkg/msg/Type"
    name: str
    array: int | None  # None: scalar; -1: unbounded sequence; n: fixed array of n
    default: str | None


def _full(name: str, package: str) -> str:
    if name in _PRIMITIVES or name == "string":
        return name
    parts = name.split("/")
    if len(parts) == 1:
        return f"{package}/msg/{name}"
    return f"{parts[0]}/msg/{parts[-1]}"


@cache
def _fields(type_name: str) -> tuple[_Field, ...]:
    package, _, short = type_name.split("/")
    path = MSG_DIR / package / "msg" / f"{short}.msg"
    if not path.is_file():
        raise ValueError(f"unknown ROS 2 message type {type_name!r}; known: {KNOWN_TYPES}")
    out = []
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        typ, rest = line.split(None, 1)
        name, *default = rest.split(None, 1)
        if "=" in name or (default and default[0].startswith("=")):
            continue  # a constant
        array: int | None = None
        if typ.endswith("]"):
            typ, size = typ[:-1].split("[")
            array = int(size) if size else -1
        out.append(_Field(_full(typ, package), name, array, default[0] if default else None))
    return tuple(out)


def _dependencies(type_name: str, seen: dict[str, None]) -> None:
    for f in _fields(type_name):
        if "/" in f.type and f.type not in seen:
            seen[f.type] = None
            _dependencies(f.type, seen)


@cache
def msgdef(type_name: str) -> str:
    """The ``ros2msg`` schema text of ``type_name`` (``pkg/msg/Type``) with its dependencies."""
    text = (MSG_DIR / type_name).with_suffix(".msg")
    parts = [text.read_text(encoding="utf-8").strip()]
    deps: dict[str, None] = {}
    _dependencies(type_name, deps)
    for dep in deps:
        pkg, _, short = dep.split("/")
        body = (MSG_DIR / pkg / "msg" / f"{short}.msg").read_text(encoding="utf-8").strip()
        parts.append(f"{_SEPARATOR}\nMSG: {pkg}/{short}\n{body}")
    return "\n".join(parts) + "\n"


class _Buffer:
    __slots__ = ("data",)

    def __init__(self) -> None:
        self.data = bytearray(b"\x00\x01\x00\x00")

    def align(self, size: int) -> None:
        pad = -(len(self.data) - 4) % size
        if pad:
            self.data += bytes(pad)


Writer = Callable[[_Buffer, Any], None]


def _primitive_writer(fmt: str, size: int, default: Any) -> Writer:
    pack = struct.Struct("<" + fmt).pack

    def write(buf: _Buffer, value: Any) -> None:
        buf.align(size)
        buf.data += pack(default if value is None else value)

    return write


def _string_writer(buf: _Buffer, value: Any) -> None:
    raw = ("" if value is None else str(value)).encode("utf-8") + b"\x00"
    buf.align(4)
    buf.data += struct.pack("<I", len(raw)) + raw


def _primitive_array_writer(fmt: str, size: int, length: int) -> Writer:
    dtype = np.dtype(_NUMPY[fmt])

    def write(buf: _Buffer, value: Any) -> None:
        if isinstance(value, bytes | bytearray | memoryview) and size == 1:
            arr_bytes = bytes(value)
            n = len(arr_bytes)
        else:
            if value is None:
                value = np.zeros(max(length, 0), dtype=dtype)
            arr = np.asarray(value, dtype=dtype).ravel()
            n = arr.size
            arr_bytes = arr.tobytes()
        if length >= 0 and n != length:
            raise ValueError(f"fixed array of {length} given {n} values")
        if length < 0:
            buf.align(4)
            buf.data += struct.pack("<I", n)
        if n:
            buf.align(size)
            buf.data += arr_bytes

    return write


def _field_writer(f: _Field) -> Writer:
    if f.type == "string":
        if f.array is None:
            return _string_writer

        def strings(buf: _Buffer, value: Any) -> None:
            items = list(value or [])
            if f.array is not None and f.array < 0:
                buf.align(4)
                buf.data += struct.pack("<I", len(items))
            for item in items:
                _string_writer(buf, item)

        return strings
    if f.type in _PRIMITIVES:
        fmt, size = _PRIMITIVES[f.type]
        if f.array is not None:
            return _primitive_array_writer(fmt, size, f.array)
        default: Any = False if fmt == "?" else 0
        if f.default is not None:
            default = float(f.default) if fmt in "fd" else int(f.default)
        return _primitive_writer(fmt, size, default)
    nested = _message_writer(f.type)
    if f.array is None:
        return nested

    def sequence(buf: _Buffer, value: Any) -> None:
        items = list(value or [])
        if f.array is not None and f.array < 0:
            buf.align(4)
            buf.data += struct.pack("<I", len(items))
        for item in items:
            nested(buf, item)

    return sequence


@cache
def _message_writer(type_name: str) -> Writer:
    fields = _fields(type_name)
    writers = [(f.name, _field_writer(f)) for f in fields]
    if not writers:
        def empty(buf: _Buffer, value: Any) -> None:
            buf.data += b"\x00"  # ROS 2 gives an empty struct one uint8 member

        return empty

    def write(buf: _Buffer, value: Any) -> None:
        get = (value or {}).get
        for name, w in writers:
            w(buf, get(name))

    return write


@cache
def encoder(type_name: str) -> Callable[[dict[str, Any]], bytes]:
    """``encode(message_dict) -> bytes`` for ``type_name`` (module docstring)."""
    write = _message_writer(type_name)

    def encode(message: dict[str, Any]) -> bytes:
        buf = _Buffer()
        write(buf, message)
        return bytes(buf.data)

    return encode


KNOWN_TYPES = sorted(f"{p.parent.parent.name}/msg/{p.stem}" for p in MSG_DIR.glob("*/msg/*.msg"))
