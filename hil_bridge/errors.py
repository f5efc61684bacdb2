"""Errors of the bus. Each also subclasses the builtin it refines, as python-can's do."""

from __future__ import annotations

__all__ = [
    "CodecError",
    "HilError",
    "OutputExistsError",
    "SecurityError",
    "TransportClosed",
    "TransportTimeout",
]


class HilError(Exception):
    """Base class of every echoloop bus error."""


class TransportTimeout(HilError, TimeoutError):
    """A blocking transport call did not complete in its timeout."""


class TransportClosed(HilError, ConnectionError):
    """The transport was used after :meth:`close`."""


class CodecError(HilError, ValueError):
    """A message could not be encoded or decoded (unknown type, newer version, bad layout)."""


class SecurityError(HilError, PermissionError):
    """A bind or peer was refused by the security policy (e.g. non-loopback without CURVE keys)."""


class OutputExistsError(HilError, FileExistsError):
    """An output file exists and the caller did not ask to overwrite it."""
