"""Output files that are never clobbered and never half-written.

Every command that writes a file (recordings, exports, captures, echoes, plots, forests)
writes it through :func:`atomic_output`:

1. an existing output (a file, a directory entry, or a symlink, dangling or not) is refused
   with :class:`~hil_bridge.errors.OutputExistsError` unless ``overwrite=True``;
2. an output that is one of the command's inputs is refused, with or without ``overwrite``;
3. the data go to a temporary file beside the output (``.STEM.XXXXXXXX.part.EXT``), renamed
   onto the output only when the ``with`` block ends without an exception; on an exception
   the temporary file is removed. The rename replaces a symlink itself, never its target.

Missing parent directories are created. Writers whose life is ``start()``/``stop()`` rather
than one ``with`` block (recorders, captures, CAN logs) use :class:`AtomicOutput`, the same
rules in three calls: construct (checks, creates the temporary file), :meth:`~AtomicOutput.commit`
(checks again, renames), :meth:`~AtomicOutput.discard`. A process killed in between leaves the
temporary file, never a half-written output.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from hil_bridge.errors import OutputExistsError

__all__ = ["AtomicOutput", "atomic_output", "check_output", "temporary_name"]


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:
        return a.resolve() == b.resolve()


def check_output(
    path: str | os.PathLike[str], *, overwrite: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
) -> Path:
    """Rules 1 and 2 of the module docstring, checked now; returns ``Path(path)``."""
    out = Path(path)
    for src in inputs:
        if _same_file(out, Path(src)):
            raise ValueError(f"{out}: is also an input of this command; write the output "
                             "to another file")
    if out.is_dir():
        raise IsADirectoryError(f"{out}: is a directory; expected a file name")
    if not overwrite and (out.exists() or out.is_symlink()):
        raise OutputExistsError(f"{out}: exists; pass --overwrite to replace it")
    return out


_COMPRESSED = frozenset({".gz", ".bz2", ".xz", ".zst", ".lz4"})


def temporary_name(path: Path) -> Path:
    """``.STEM.XXXXXXXX.part.EXT`` beside ``path``: hidden, unique, and with the same suffix
    (two for ``.log.gz``-like names), so writers that pick the format from the suffix
    (matplotlib, ``numpy.savez``, python-can loggers) still do."""
    suffixes = path.suffixes
    keep = 2 if len(suffixes) > 1 and path.suffix in _COMPRESSED else 1 if suffixes else 0
    ext = "".join(suffixes[len(suffixes) - keep:])
    stem = path.name[:len(path.name) - len(ext)]
    return path.with_name(f".{stem}.{secrets.token_hex(4)}.part{ext}")


class AtomicOutput:
    """One output file written through a temporary file beside it (module docstring).

    ``AtomicOutput(path, overwrite=False, inputs=())`` refuses the output now (rules 1 and 2)
    and creates ``tmp``; write ``tmp``, then :meth:`commit` (rules re-checked, then renamed
    onto ``path``) or :meth:`discard`. Both are idempotent; after either, the other does
    nothing.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, overwrite: bool = False,
        inputs: Iterable[str | os.PathLike[str]] = (),
    ) -> None:
        self.inputs = tuple(inputs)
        self.overwrite = overwrite
        self.path = check_output(path, overwrite=overwrite, inputs=self.inputs)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = temporary_name(self.path)
        with open(self.tmp, "xb"):
            pass
        self.done = False

    def commit(self) -> Path:
        """Rename the temporary file onto the output; returns the output path."""
        if not self.done:
            check_output(self.path, overwrite=self.overwrite, inputs=self.inputs)
            os.replace(self.tmp, self.path)
            self.done = True
        return self.path

    def discard(self) -> None:
        """Remove the temporary file (the output is left as it was)."""
        if not self.done:
            self.done = True
            with suppress(FileNotFoundError):
                self.tmp.unlink()


@contextmanager
def atomic_output(
    path: str | os.PathLike[str], *, overwrite: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
) -> Iterator[Path]:
    """Yield a temporary path to write; it becomes ``path`` when the block succeeds."""
    out = AtomicOutput(path, overwrite=overwrite, inputs=inputs)
    try:
        yield out.tmp
        out.commit()
    finally:
        out.discard()
