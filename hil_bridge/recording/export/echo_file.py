"""One echo to a file, the format chosen by the extension: ``.npz``, ``.mat`` or ``.wav``.

- ``.npz``: ``echo`` (N,) or (C, N) float64 (re A0, t = 0 at emission), ``fs`` (Hz) and the
  ping's parameters as arrays of their own (``meta`` keys);
- ``.mat`` (MATLAB v5, ``load('echo.mat')``): ``echo`` N×C (one column per channel, MATLAB's
  layout), ``fs``, and a struct ``ping`` holding ``meta``;
- ``.wav``: one WAV channel per echo channel at the echo's sample rate, either 32-bit IEEE
  float (the values re A0 unchanged) or 16-bit PCM scaled so the peak is 32767 (the scale is
  returned: ``value = sample / 32767 * full_scale``).

Any other extension is refused, naming the accepted ones.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.outputs import atomic_output, check_output

__all__ = ["ECHO_FORMATS", "WAV_FORMATS", "check_echo_output", "write_echo"]

ECHO_FORMATS = (".npz", ".mat", ".wav")
WAV_FORMATS = ("float32", "int16")


def check_echo_output(path: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
    """Refuse now (before any work) an unknown extension or an existing file."""
    out = Path(path)
    if out.suffix.lower() not in ECHO_FORMATS:
        raise ValueError(f"{out}: unknown echo file extension {out.suffix!r}; expected one of "
                         f"{list(ECHO_FORMATS)}")
    return check_output(out, overwrite=overwrite)


def write_echo(
    path: str | os.PathLike[str],
    samples: NDArray[np.floating],
    fs: float,
    meta: Mapping[str, Any],
    *,
    overwrite: bool = False,
    wav_format: str = "float32",
) -> dict[str, Any]:
    """Write one echo (module docstring); returns what was written (``format``, and for int16
    WAV the ``full_scale`` amplitude that maps to 32767)."""
    out = check_echo_output(path, overwrite=overwrite)
    ext = out.suffix.lower()
    if wav_format not in WAV_FORMATS:
        raise ValueError(f"wav format: expected one of {list(WAV_FORMATS)}, got {wav_format!r}")
    x = np.asarray(samples, dtype=np.float64)
    info: dict[str, Any] = {"format": ext[1:], "path": str(out)}
    with atomic_output(out, overwrite=overwrite) as tmp, open(tmp, "wb") as fh:
        if ext == ".npz":
            arrays: dict[str, Any] = {k: np.asarray(v) for k, v in meta.items()}
            np.savez(fh, echo=x, fs=np.float64(fs), **arrays)
        elif ext == ".mat":
            from scipy.io import savemat

            savemat(fh, {"echo": np.atleast_2d(x).T, "fs": float(fs), "ping": dict(meta)},
                    format="5", oned_as="column")
        else:
            from scipy.io import wavfile

            data = np.atleast_2d(x).T
            if wav_format == "int16":
                full = float(np.max(np.abs(data))) or 1.0
                data = np.round(data / full * 32767.0).astype(np.int16)
                info["full_scale"] = full
            else:
                data = data.astype(np.float32)
            rate = round(fs)
            if rate != fs:
                raise ValueError(f"{out}: WAV needs an integer sample rate, got {fs} Hz")
            wavfile.write(fh, rate, data)
            info["wav_format"] = wav_format
    return info
