"""Configuration files: UTF-8 text, YAML documents, ``.npz`` archives and ``KEY=VALUE`` overrides.

Every reader fails with a :class:`sim_core.config.ConfigError` naming the file (and line, for
YAML) when the file cannot be read, is not what it claims to be, or is damaged; validation of the
data itself is :func:`sim_core.config.from_dict`.
"""

from __future__ import annotations

import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim_core.config import ConfigError

__all__ = ["NPZ_MAX_BYTES", "load_npz", "load_yaml", "parse_override", "read_text"]


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
    return {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}


def load_npz(path: str | Path, *, max_bytes: int = NPZ_MAX_BYTES) -> dict[str, Any]:
    """Every array of an ``.npz`` file, checked before it is read: ``ConfigError`` naming the
    file when it is empty, not a zip archive, damaged (CRC), holds pickled objects, an array
    whose header declares more data than the archive holds (a truncated file or a forged
    shape), or more than ``max_bytes`` in all."""
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
