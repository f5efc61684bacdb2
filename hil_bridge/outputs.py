"""Output files that are never clobbered and never half-written.

Every command that writes a file (recordings, exports, captures, echoes, plots, forests)
writes it through :func:`atomic_output`:

1. an existing output (a file, a directory entry, or a symlink, dangling or not) is refused
   with :class:`~hil_bridge.errors.OutputExistsError` unless ``overwrite=True``;
2. an output that is one of the command's inputs is refused, with or without ``overwrite``;
3. the data go to a temporary file beside the output (``.NAME.XXXXXXXX.part``), renamed
   onto the output only when the ``with`` block ends without an exception; on an exception
   the temporary file is removed. The rename replaces a symlink itself, never its target.

Missing parent directories are created.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from hil_bridge.errors import OutputExistsError

__all__ = ["atomic_output", "check_output"]


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


@contextmanager
def atomic_output(
    path: str | os.PathLike[str], *, overwrite: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
) -> Iterator[Path]:
    """Yield a temporary path to write; it becomes ``path`` when the block succeeds."""
    inputs = tuple(inputs)
    out = check_output(path, overwrite=overwrite, inputs=inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{secrets.token_hex(4)}.part")
    with open(tmp, "xb"):
        pass
    try:
        yield tmp
        check_output(out, overwrite=overwrite, inputs=inputs)
        os.replace(tmp, out)
    finally:
        with suppress(FileNotFoundError):
            tmp.unlink()
