"""Column tables: CSV with a header row and NPZ with one array per column.

Columns: ``t`` (s) and a position, either ``x, y, z`` (m, local ENU) or ``lat, lon, alt``
(degrees, degrees, metres; converted to ENU about the first fix or ``origin``). Optional:
``heading`` (rad from +x towards +y), ``bank`` (rad, positive in a left turn), ``airspeed``
(m/s) — derived from the track when absent —, an attitude ``qw, qx, qy, qz`` (world-from-body
ENU/FLU), and for multi-vehicle traces (``echoloop swarm``, :class:`sim_core.soaring.Trace`)
``id`` and ``alive`` (rows with ``alive == 0`` are dropped). A swarm trace NPZ has ``t`` (T,)
and every other column (T, N), the vehicle id being the column index. In CSV, ``#`` lines are
comments and ``true``/``false`` read as 1/0; extra columns are ignored. A non-finite value in
a column that is read, or a CSV whose last line has no line end (cut short), is refused; so is
a ``topic`` (a table has one position).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_bridge.files.config import load_npz, read_text
from hil_bridge.recording.logs.track import PoseLog

__all__ = ["LOCAL_COLUMNS", "read_csv", "read_npz"]

#: a local table's position columns; ``GEODETIC_COLUMNS`` the geodetic alternative
LOCAL_COLUMNS = ("x", "y", "z")
GEODETIC_COLUMNS = ("lat", "lon", "alt")
_QUAT = ("qw", "qx", "qy", "qz")


def _no_topic(path: Path, topic: str | None, fmt: str) -> None:
    """A table has one position (its columns): a ``topic`` is refused, not ignored."""
    if topic is not None:
        raise ValueError(f"{path}: topic {topic!r}: a {fmt} table has no topics (its position "
                         "is the columns x, y, z or lat, lon, alt); leave --topic out")


def read_csv(path: Path, *, vehicle_id: int | None = None, topic: str | None = None) -> PoseLog:
    """A CSV table (module docstring) as a :class:`PoseLog`."""
    _no_topic(path, topic, "CSV")
    return _pose_log(path, _read_csv_columns(path), vehicle_id, "CSV")


def read_npz(path: Path, *, vehicle_id: int | None = None, topic: str | None = None) -> PoseLog:
    """An NPZ table (module docstring) as a :class:`PoseLog`."""
    _no_topic(path, topic, "NPZ")
    cols = load_npz(path)  # damaged archives, forged shapes, pickles: one line naming the file
    if ("x" in cols and cols["x"].ndim == 2) or ("lat" in cols and cols["lat"].ndim == 2):
        cols = _wide_columns(path, cols, vehicle_id)
        vehicle_id = None
    return _pose_log(path, cols, vehicle_id, "NPZ")


def _pose_log(
    p: Path, cols: dict[str, NDArray[Any]], vehicle_id: int | None, fmt: str
) -> PoseLog:
    if all(c in cols for c in LOCAL_COLUMNS):
        names, frame = LOCAL_COLUMNS, "enu"
    elif all(c in cols for c in GEODETIC_COLUMNS):
        names, frame = GEODETIC_COLUMNS, "geodetic"
    else:
        want = GEODETIC_COLUMNS if any(c in cols for c in GEODETIC_COLUMNS) else LOCAL_COLUMNS
        missing = [c for c in want if c not in cols]
        raise ValueError(f"{p}: missing column(s) {missing}; expected t and x, y, z (m ENU) or "
                         f"lat, lon, alt (found {sorted(cols)})")
    if "t" not in cols:
        raise ValueError(f"{p}: missing column(s) ['t']; expected t and x, y, z (m ENU) or "
                         f"lat, lon, alt (found {sorted(cols)})")
    mask = np.ones(np.asarray(cols["t"]).shape, dtype=bool)
    if "id" in cols:
        ids = np.asarray(cols["id"]).astype(np.int64)
        present = sorted(set(ids.tolist()))
        if vehicle_id is None:
            if len(present) > 1:
                raise ValueError(f"{p}: holds vehicles {present}; choose one with an id")
        elif vehicle_id not in present:
            raise ValueError(f"{p}: no rows for id {vehicle_id}; ids present: {present}")
        else:
            mask &= ids == vehicle_id
    elif vehicle_id is not None:
        raise ValueError(f"{p}: has no 'id' column, so id {vehicle_id} cannot be selected")
    if "alive" in cols:
        mask &= np.asarray(cols["alive"]).astype(np.float64) != 0

    def col(name: str) -> NDArray[np.float64]:
        values = np.asarray(cols[name], dtype=np.float64)[mask]
        bad = ~np.isfinite(values)
        if bad.any():
            raise ValueError(f"{p}: column {name!r} is not finite in row {int(np.argmax(bad))} "
                             "(of the rows read)")
        return values

    def opt(name: str) -> NDArray[np.float64] | None:
        return col(name) if name in cols else None

    position = np.stack([col(n) for n in names], axis=1)
    quat = np.stack([col(c) for c in _QUAT], axis=1) if all(c in cols for c in _QUAT) else None
    t = col("t")
    return PoseLog(
        format=fmt, source=f"columns t, {', '.join(names)}", t=t, position=position,
        frame=frame,  # type: ignore[arg-type]
        att_t=None if quat is None else t, att_q=quat,
        att_source="columns qw, qx, qy, qz" if quat is not None else "",
        heading=opt("heading"), bank=opt("bank"), speed=opt("airspeed"),
        vehicle_id=vehicle_id,
    )


def _wide_columns(
    p: Path, cols: dict[str, NDArray[Any]], vehicle_id: int | None
) -> dict[str, NDArray[Any]]:
    """Column ``vehicle_id`` of a wide NPZ trace (``t`` (T,), the others (T, N), as written by
    ``hil_bridge.files.soaring.save_trace_npz``)."""
    n = np.asarray(cols["x" if "x" in cols else "lat"]).shape[1]
    if vehicle_id is None:
        if n > 1:
            raise ValueError(f"{p}: holds vehicles {list(range(n))}; choose one with an id")
        vehicle_id = 0
    if not 0 <= vehicle_id < n:
        raise ValueError(f"{p}: no vehicle {vehicle_id}; ids present: {list(range(n))}")
    out = {"t": np.asarray(cols["t"])}
    for name, arr in cols.items():
        if name != "t":
            a = np.asarray(arr)
            out[name] = a[:, vehicle_id] if a.ndim == 2 else a
    return out


def _read_csv_columns(p: Path) -> dict[str, NDArray[Any]]:
    text = read_text(p)  # unreadable or not UTF-8: one line naming the file
    if not text.strip():
        raise ValueError(f"{p}: empty CSV file")
    if not text.endswith("\n"):
        raise ValueError(f"{p}: the last line has no line end: the file was cut short? (end "
                         "it with a newline if it is complete)")
    reader = csv.reader(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    header = next(reader, None)
    if header is None:
        raise ValueError(f"{p}: empty CSV file")
    names = [h.strip() for h in header]
    rows: list[list[float]] = []
    for lineno, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != len(names):
            raise ValueError(f"{p}:{lineno}: expected {len(names)} fields, got {len(row)}")
        try:
            rows.append([_csv_float(v) for v in row])
        except ValueError:
            raise ValueError(f"{p}:{lineno}: non-numeric field in {row}") from None
    data = np.asarray(rows, dtype=np.float64).reshape(len(rows), len(names))
    return {name: data[:, i] for i, name in enumerate(names)}


def _csv_float(text: str) -> float:
    s = text.strip().lower()
    if s in ("true", "false"):
        return 1.0 if s == "true" else 0.0
    return float(s)
