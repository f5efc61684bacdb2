"""Plain-data configuration: YAML -> ``dict`` -> frozen dataclass, validated once.

:func:`from_dict` builds a (nested) frozen dataclass from a mapping, rejecting unknown keys and
values of the wrong type with a :class:`ConfigError` (a ``ValueError``) that names the dotted key
path and the expected form. Supported field types: ``int``, ``float`` (ints accepted), ``bool``,
``str``, ``None``, unions/optionals, ``Literal``, ``tuple[X, ...]``/``tuple[X, Y]``, ``list[X]``,
``dict[str, X]``, nested dataclasses and ``Any``.

Precedence wherever several sources meet (CLI > environment > file) is applied by the caller
*before* validation with :func:`apply_overrides`, so validation happens once, on the merged dict.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

import yaml

__all__ = [
    "NPZ_MAX_BYTES",
    "ConfigError",
    "apply_overrides",
    "from_dict",
    "load_npz",
    "load_yaml",
    "parse_override",
    "read_text",
]

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the key and expected form."""


def _type_name(tp: Any) -> str:
    if tp is type(None):
        return "null"
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _convert(value: Any, tp: Any, path: str) -> Any:
    if tp is Any:
        return value
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, path)
            except ConfigError:
                continue
        raise ConfigError(f"{path}: expected {_type_name(tp)}, got {value!r}")
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{path}: expected one of {list(allowed)}, got {value!r}")
        return value
    if tp is type(None):
        if value is not None:
            raise ConfigError(f"{path}: expected null, got {value!r}")
        return None
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected a boolean (true/false), got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{path}: expected a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{path}: expected a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {value!r}")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{path}: expected a list of {len(args)} items, got {value!r}")
        pairs = enumerate(zip(value, args, strict=True))
        return tuple(_convert(v, a, f"{path}[{i}]") for i, (v, a) in pairs)
    if origin is list:
        (arg,) = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        return [_convert(v, arg, f"{path}[{i}]") for i, v in enumerate(value)]
    if origin in (dict, Mapping, typing.Mapping):
        key_tp, val_tp = get_args(tp)
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path}: expected a mapping, got {value!r}")
        return {
            _convert(k, key_tp, f"{path}.<key>"): _convert(v, val_tp, f"{path}.{k}")
            for k, v in value.items()
        }
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if isinstance(value, tp):
            return value
        return from_dict(tp, value, path=path)
    if isinstance(tp, type):
        if isinstance(value, tp):
            return value
        raise ConfigError(f"{path}: expected {_type_name(tp)}, got {value!r}")
    raise TypeError(f"{path}: unsupported field type {tp!r}")


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return get_type_hints(cls)


def from_dict(cls: type[T], data: Any, *, path: str = "") -> T:
    """Build dataclass ``cls`` from mapping ``data``; unknown keys and bad types raise.

    Missing keys take the field defaults; a missing key without a default raises. After the
    fields are built, the dataclass's own ``__post_init__`` runs its range checks.
    """
    if not (dataclasses.is_dataclass(cls) and isinstance(cls, type)):
        raise TypeError(f"{cls!r} is not a dataclass type")
    where = path or cls.__name__
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping of {cls.__name__} fields, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(map(str, data)) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {unknown}; expected some of {sorted(fields)}"
        )
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        key_path = f"{path}.{name}" if path else name
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], key_path)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{key_path}: required key is missing")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def read_text(path: str | Path) -> str:
    """A UTF-8 text file; ``ConfigError`` naming the file when it cannot be read or is not
    text (binary data, another encoding)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read ({exc.strerror or exc})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte {data[exc.start]:#04x} at offset "
                          f"{exc.start}): a binary or damaged file?") from None


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file; ``ConfigError`` naming the file (and line) when it cannot be read, is
    not UTF-8 text, is not valid YAML, or holds no document at all (empty or only comments:
    a configuration file that says nothing is taken for a mistake, not for the defaults)."""
    p = Path(path)
    text = read_text(p)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{p}:{mark.line + 1}" if mark is not None else str(p)
        raise ConfigError(f"{where}: invalid YAML ({getattr(exc, 'problem', exc)})") from None
    if data is None:
        raise ConfigError(f"{p}: empty, no YAML document (write '{{}}' for all defaults)")
    return data


#: the most bytes :func:`load_npz` reads from one file
NPZ_MAX_BYTES = 4 << 30


def _npy_headers() -> dict[tuple[int, int], Any]:
    import numpy as np

    return {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


def load_npz(path: str | Path, *, max_bytes: int = NPZ_MAX_BYTES) -> dict[str, Any]:
    """Every array of an ``.npz`` file, checked before it is read: ``ConfigError`` naming the
    file when it is empty, not a zip archive, damaged (CRC), holds pickled objects, an array
    whose header declares more data than the archive holds (a truncated file or a forged
    shape), or more than ``max_bytes`` in all."""
    import zipfile

    import numpy as np

    p = Path(path)
    arrays: dict[str, Any] = {}
    total = 0
    headers = _npy_headers()
    try:
        with zipfile.ZipFile(p) as zf:
            for info in zf.infolist():
                name = info.filename.removesuffix(".npy")
                with zf.open(info) as member:
                    version = np.lib.format.read_magic(member)
                    read_header = headers.get(version)
                    if read_header is None:
                        raise ConfigError(f"{p}: array {name!r} has .npy format {version}; "
                                          "expected 1.0 or 2.0")
                    shape, fortran, dtype = read_header(member)
                    if dtype.hasobject:
                        raise ConfigError(f"{p}: array {name!r} holds Python objects "
                                          "(pickled data is never loaded)")
                    need = math.prod(shape) * dtype.itemsize
                    header = member.tell()
                    if header + need != info.file_size:
                        raise ConfigError(
                            f"{p}: array {name!r} declares shape {tuple(shape)} of {dtype} "
                            f"({need} bytes) but the file holds {info.file_size - header}: "
                            "truncated or forged")
                    total += need
                    if total > max_bytes:
                        raise ConfigError(f"{p}: more than {max_bytes} bytes of arrays")
                    data = np.frombuffer(member.read(need), dtype=dtype)
                    arrays[name] = data.reshape(shape, order="F" if fortran else "C").copy()
    except ConfigError:
        raise
    except zipfile.BadZipFile as exc:
        raise ConfigError(f"{p}: not a readable .npz archive ({exc})") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except (ValueError, EOFError, KeyError, TypeError) as exc:
        raise ConfigError(f"{p}: damaged .npz archive ({type(exc).__name__}: {exc})") from None
    return arrays


def parse_override(text: str) -> tuple[str, Any]:
    """Parse ``KEY=VALUE`` (VALUE in YAML syntax: ``3``, ``1e-3``, ``true``, ``[1, 2]``)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"override {text!r}: expected KEY=VALUE")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    if isinstance(value, str):
        # YAML 1.1 reads "1e-3" (no dot) as a string; numbers are what users mean
        try:
            value = float(value)
        except ValueError:
            pass
    return key.strip(), value


def apply_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Return a copy of ``data`` with dotted-key ``overrides`` (``a.b.c``) applied."""
    out: dict[str, Any] = _deep_copy(data)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node = out
        for part in parts[:-1]:
            child = node.get(part)
            if child is None:
                child = {}
                node[part] = child
            elif not isinstance(child, dict):
                raise ConfigError(f"override {dotted!r}: {part!r} is not a mapping")
            node = child
        node[parts[-1]] = value
    return out


def _deep_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    return {k: _deep_copy(v) if isinstance(v, Mapping) else v for k, v in data.items()}
