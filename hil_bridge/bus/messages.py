"""Bus messages: frozen, slotted dataclasses with a schema name (``TYPE``) and ``VERSION``.

Every message has ``stamp_ns: int`` (sim time from a :class:`~hil_bridge.bus.clock.SimClock`) and is
keyword-only, so a field can never be filled by position by mistake. Array fields are numpy arrays
coerced to the dtype declared in ``ARRAYS`` and made read-only, so one instance can be handed to
any number of subscribers without copying. Field names listed in ``docs/spec/protocols.md`` §1 are
binding; fields may be added (with a default) without bumping ``VERSION``; renaming or changing
the meaning of a field bumps it.

``REGISTRY`` maps ``TYPE`` → class; :func:`register` adds a class, :func:`message_class` looks one
up (``CodecError`` naming the known types when unknown).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import operator
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt

from hil_bridge.errors import CodecError

if TYPE_CHECKING:
    from sim_core.sensors import SensorTruth

__all__ = [
    "REGISTRY",
    "Clock",
    "CmdAck",
    "Diagnostics",
    "EcholoopClock",
    "FdmState",
    "GliderCmd",
    "GliderNeighbors",
    "GliderState",
    "Message",
    "PointCloud",
    "SonarEcho",
    "SonarPing",
    "SurfaceCmd",
    "ThermalMarkers",
    "fdm_truth",
    "message_class",
    "register",
    "state_quaternion",
    "state_quaternions",
]

REGISTRY: dict[str, type[Message]] = {}

M = TypeVar("M", bound="type[Message]")

_FROZEN = {"frozen": True, "slots": True, "kw_only": True, "eq": False}


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return False
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return bool(a == b)


class Message:
    """Base of every bus message (no fields of its own).

    Subclasses are ``@dataclass(frozen=True, slots=True, kw_only=True, eq=False)`` and set
    ``TYPE``, ``VERSION`` and, for array fields, ``ARRAYS = {field: dtype}``. Equality compares
    fields, arrays by dtype, shape and value (NaN equal to NaN, so codec round trips compare equal).
    """

    __slots__ = ()
    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    ARRAYS: ClassVar[Mapping[str, str]] = {}

    def __post_init__(self) -> None:
        for name, dtype in self.ARRAYS.items():
            given = getattr(self, name)
            arr = np.ascontiguousarray(given, dtype=np.dtype(dtype))
            if arr.flags.writeable:
                if arr is given or arr.base is given:
                    arr = arr.copy()  # never freeze (or alias) the caller's buffer
                arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(
            _equal(getattr(self, f.name), getattr(other, f.name))
            for f in dataclasses.fields(self)  # type: ignore[arg-type]
        )

    __hash__ = None  # type: ignore[assignment]


def register(cls: M) -> M:
    """Class decorator: add ``cls`` to :data:`REGISTRY` under ``cls.TYPE`` (unique)."""
    if not cls.TYPE or "/" not in cls.TYPE:
        raise ValueError(f"{cls.__name__}.TYPE must look like 'package/Name', got {cls.TYPE!r}")
    if not isinstance(cls.VERSION, int) or cls.VERSION < 1:
        raise ValueError(f"{cls.__name__}.VERSION must be an int >= 1, got {cls.VERSION!r}")
    if REGISTRY.get(cls.TYPE, cls) is not cls:
        raise ValueError(f"message type {cls.TYPE!r} is already registered")
    REGISTRY[cls.TYPE] = cls
    return cls


def message_class(type_name: str) -> type[Message]:
    """The registered class of ``type_name``; ``CodecError`` listing known types otherwise."""
    try:
        return REGISTRY[type_name]
    except KeyError:
        raise CodecError(
            f"unknown message type {type_name!r}; known types: {sorted(REGISTRY)}"
        ) from None


@register
@dataclasses.dataclass(**_FROZEN)
class Clock(Message):
    """``/clock``: the current sim time (spec name ``EcholoopClock``).

    ``lockstep``: the server waits for its lockstep participants at every step (docs/server.md,
    :mod:`hil_bridge.server.lockstep`), so adapters drive their devices on sim time.
    """

    TYPE: ClassVar[str] = "echoloop/Clock"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    lockstep: bool = False


EcholoopClock = Clock


@register
@dataclasses.dataclass(**_FROZEN)
class GliderState(Message):
    """``/glider/<id>/state``: pose and motion of one glider (ENU metres, radians, m/s).

    ``heading`` (from +x towards +y) and ``bank`` (the seed's sign: positive turns towards
    increasing heading) as before; the full attitude follows: ``roll``, ``pitch``, ``yaw`` (rad,
    Z-Y-X Euler angles of the world-from-body rotation, world ENU, body FLU: a left turn has
    ``roll = -bank``, a glide ``pitch > 0`` (nose down)), that rotation as the unit quaternion
    ``qw, qx, qy, qz``, and ``roll_rate``, ``pitch_rate``, ``yaw_rate`` (rad/s, body axes). NaN:
    not given by the publisher (e.g. a recording older than these fields; see
    :func:`state_quaternions`).
    """

    TYPE: ClassVar[str] = "echoloop/GliderState"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    x: float
    y: float
    z: float
    heading: float
    bank: float
    airspeed: float
    vz: float
    alive: bool = True
    glider_id: int = 0
    step: int = 0
    roll: float = math.nan
    pitch: float = math.nan
    yaw: float = math.nan
    qw: float = math.nan
    qx: float = math.nan
    qy: float = math.nan
    qz: float = math.nan
    roll_rate: float = math.nan
    pitch_rate: float = math.nan
    yaw_rate: float = math.nan


def state_quaternions(states: Sequence[GliderState]) -> npt.NDArray[np.float64]:
    """The world-from-body attitudes ``[w, x, y, z]`` (K, 4) of K states: each state's
    quaternion, or, for a state whose publisher gave none (NaN), the attitude the flight model
    gives a glider at its ``heading``, ``bank`` and ``airspeed``
    (:func:`sim_core.flight.glide_attitude`: roll −bank, pitch the SB-XC polar's glide angle
    through the air). The live view and every exporter take attitudes from here."""
    q = np.array([[s.qw, s.qx, s.qy, s.qz] for s in states], dtype=np.float64).reshape(-1, 4)
    given = np.all(np.isfinite(q), axis=1)
    if not given.all():
        from sim_core.flight import glide_attitude

        old = [s for s, ok in zip(states, given, strict=True) if not ok]
        fields = np.array([[s.heading, s.bank, s.airspeed] for s in old], dtype=np.float64)
        q[~given] = glide_attitude(fields[:, 0], fields[:, 1], fields[:, 2]).quat
    return q


def state_quaternion(msg: GliderState) -> npt.NDArray[np.float64]:
    """The world-from-body attitude ``[w, x, y, z]`` (4,) of one state
    (:func:`state_quaternions`)."""
    return state_quaternions([msg])[0]


@register
@dataclasses.dataclass(**_FROZEN)
class GliderCmd(Message):
    """``/glider/<id>/cmd``: autopilot command (bank rad, airspeed m/s)."""

    TYPE: ClassVar[str] = "echoloop/GliderCmd"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    bank_cmd: float
    airspeed_cmd: float
    glider_id: int = 0
    step: int = 0


@register
@dataclasses.dataclass(**_FROZEN)
class SurfaceCmd(Message):
    """``/glider/<id>/surfaces``: control surfaces of a 6-DoF vehicle (JSBSim's normalised
    commands: ``aileron``, ``elevator``, ``rudder`` in [-1, 1], positive elevator nose down;
    ``throttle`` in [0, 1]); ``step``: the state step it answers (lockstep); ``hold``: it
    answers the step and changes no surface (a firmware's clock whose surfaces come by another
    wire, e.g. ArduPilot SITL's JSON frames while DroneCAN drives its servos)."""

    TYPE: ClassVar[str] = "echoloop/SurfaceCmd"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    aileron: float
    elevator: float
    throttle: float
    rudder: float
    glider_id: int = 0
    step: int = 0
    hold: bool = False


@register
@dataclasses.dataclass(**_FROZEN)
class FdmState(Message):
    """``/glider/<id>/fdm``: what an autopilot's sensors need of a 6-DoF vehicle, each tick
    beside its ``GliderState``: position ``x, y, z`` m and velocity ``vx, vy, vz`` m/s (world
    ENU), attitude ``qw, qx, qy, qz`` (world-from-body, ENU from FLU), body rates ``p, q, r``
    rad/s and specific force ``fx, fy, fz`` m/s² (body FLU: +9.81 on z at rest), true
    ``airspeed`` m/s; ``step`` as the state's; the flight model's own geodetic position
    ``lat``, ``lon`` deg and ``alt`` m above the WGS-84 ellipsoid (NaN: not given, a recording
    older than these fields). :func:`fdm_truth` turns states into what sensors are read from."""

    TYPE: ClassVar[str] = "echoloop/FdmState"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    glider_id: int
    step: int
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    qw: float
    qx: float
    qy: float
    qz: float
    p: float
    q: float
    r: float
    fx: float
    fy: float
    fz: float
    airspeed: float
    lat: float = math.nan
    lon: float = math.nan
    alt: float = math.nan


#: an FdmState's truth, in :data:`sim_core.sensors.kernels.TRUTH_COLUMNS` order
_TRUTH = operator.attrgetter("lat", "lon", "alt", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "p",
                             "q", "r", "fx", "fy", "fz", "airspeed")


def fdm_truth(states: Sequence[FdmState]) -> SensorTruth:
    """The truth of K 6-DoF states as :class:`sim_core.sensors.SensorTruth` (rows in order),
    what :class:`sim_core.sensors.SensorSuite` reads sensors from."""
    from sim_core.sensors import SensorTruth

    flat = itertools.chain.from_iterable(map(_TRUTH, states))
    return SensorTruth(np.fromiter(flat, np.float64).reshape(-1, 17))


@register
@dataclasses.dataclass(**_FROZEN)
class GliderNeighbors(Message):
    """``/glider/<id>/neighbors``: the neighbours one glider observes (K of them).

    ``ids`` shape (K,) int32; every other array shape (K,) float64 in the units of
    :class:`GliderState`.
    """

    TYPE: ClassVar[str] = "echoloop/GliderNeighbors"
    VERSION: ClassVar[int] = 1
    ARRAYS: ClassVar[Mapping[str, str]] = {
        "ids": "<i4",
        "x": "<f8",
        "y": "<f8",
        "z": "<f8",
        "heading": "<f8",
        "bank": "<f8",
        "airspeed": "<f8",
        "vz": "<f8",
    }

    stamp_ns: int
    glider_id: int
    ids: npt.NDArray[Any]
    x: npt.NDArray[Any]
    y: npt.NDArray[Any]
    z: npt.NDArray[Any]
    heading: npt.NDArray[Any]
    bank: npt.NDArray[Any]
    airspeed: npt.NDArray[Any]
    vz: npt.NDArray[Any]
    step: int = 0

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        k = self.ids.shape
        for name in self.ARRAYS:
            if getattr(self, name).shape != k or len(k) != 1:
                raise ValueError(
                    f"GliderNeighbors.{name} must have shape {k} like ids (1-D), "
                    f"got {getattr(self, name).shape}"
                )


@register
@dataclasses.dataclass(**_FROZEN)
class SonarPing(Message):
    """``/sonar/<id>/ping``: a ping request; az/el relative to the body's forward axis (rad).

    ``beamwidth`` is the full one-way −3 dB width (rad); ``encoding`` is the sample encoding the
    head asked for (0 int16 real, 1 int16 IQ, 2 float32 real; spec §2). ``next_ns``: the sim
    time of this sonar's next ping when its head pings on sim time (lockstep; the server waits
    for that ping), -1 when unknown.
    """

    TYPE: ClassVar[str] = "echoloop/SonarPing"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    ping_seq: int
    az: float
    el: float
    beamwidth: float
    encoding: int = 2
    sonar_id: int = 0
    next_ns: int = -1


@register
@dataclasses.dataclass(**_FROZEN)
class SonarEcho(Message):
    """``/sonar/<id>/echo``: the echo of one ping.

    ``samples`` float32, shape (n,) or (channels, n), at ``fs`` Hz. ``error_bound`` is the
    synthesiser's bound (NaN when it gives none). Where the sonar was when it pinged:
    ``position`` (3,) m world ENU, ``orientation`` (4,) world-from-sonar ``[w, x, y, z]``,
    ``boresight`` (3,) the beam axis, a world unit vector, at sim time ``emit_ns``;
    ``boresight_body`` (3,) the beam axis in its vehicle's body axes (FLU: the mount's rotation
    of the ping's az/el), what a range finder on the vehicle reports its orientation by. NaN
    arrays and ``emit_ns`` 0: not given (a publisher older than these fields).
    """

    TYPE: ClassVar[str] = "echoloop/SonarEcho"
    VERSION: ClassVar[int] = 1
    ARRAYS: ClassVar[Mapping[str, str]] = {
        "samples": "<f4", "position": "<f8", "orientation": "<f8", "boresight": "<f8",
        "boresight_body": "<f8",
    }

    stamp_ns: int
    ping_seq: int
    fs: float
    samples: npt.NDArray[Any]
    leaves_in_beam: int
    fidelity: str
    sonar_id: int = 0
    dropped: int = 0
    error_bound: float = math.nan
    compute_ns: int = 0
    position: npt.NDArray[Any] = dataclasses.field(default_factory=lambda: np.full(3, np.nan))
    orientation: npt.NDArray[Any] = dataclasses.field(
        default_factory=lambda: np.full(4, np.nan)
    )
    boresight: npt.NDArray[Any] = dataclasses.field(default_factory=lambda: np.full(3, np.nan))
    emit_ns: int = 0
    boresight_body: npt.NDArray[Any] = dataclasses.field(
        default_factory=lambda: np.full(3, np.nan)
    )

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if self.samples.ndim not in (1, 2):
            raise ValueError(
                f"SonarEcho.samples must have shape (n,) or (channels, n), "
                f"got {self.samples.shape}"
            )
        for name, n in (("position", 3), ("orientation", 4), ("boresight", 3),
                        ("boresight_body", 3)):
            if getattr(self, name).shape != (n,):
                raise ValueError(
                    f"SonarEcho.{name} must have shape ({n},), got {getattr(self, name).shape}"
                )


@register
@dataclasses.dataclass(**_FROZEN)
class Diagnostics(Message):
    """``/diagnostics``: one node's counters (sent, received, dropped, ...), flat ``name → number``.

    Per-topic counters are keyed ``"<counter>:<topic>"`` (e.g. ``"dropped:/glider/0/state"``).
    """

    TYPE: ClassVar[str] = "echoloop/Diagnostics"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    node: str
    counters: dict[str, int | float]


@register
@dataclasses.dataclass(**_FROZEN)
class CmdAck(Message):
    """``<topic>/ack``: acknowledges message ``seq`` of publisher ``src`` on ``topic``."""

    TYPE: ClassVar[str] = "echoloop/CmdAck"
    VERSION: ClassVar[int] = 1

    stamp_ns: int
    topic: str
    src: str
    seq: int
    node: str = ""


@register
@dataclasses.dataclass(**_FROZEN)
class ThermalMarkers(Message):
    """Thermal centres for viewers: arrays shape (K,), x/y metres ENU, radius m, w_max m/s."""

    TYPE: ClassVar[str] = "echoloop/ThermalMarkers"
    VERSION: ClassVar[int] = 1
    ARRAYS: ClassVar[Mapping[str, str]] = {
        "x": "<f8",
        "y": "<f8",
        "radius": "<f8",
        "w_max": "<f8",
    }

    stamp_ns: int
    x: npt.NDArray[Any]
    y: npt.NDArray[Any]
    radius: npt.NDArray[Any]
    w_max: npt.NDArray[Any]


@register
@dataclasses.dataclass(**_FROZEN)
class PointCloud(Message):
    """A point set for viewers (e.g. forest leaves): ``points`` (N, 3) float32 metres ENU and
    optional per-point ``intensity`` (N,) float32 (empty when absent)."""

    TYPE: ClassVar[str] = "echoloop/PointCloud"
    VERSION: ClassVar[int] = 1
    ARRAYS: ClassVar[Mapping[str, str]] = {"points": "<f4", "intensity": "<f4"}

    stamp_ns: int
    points: npt.NDArray[Any]
    intensity: npt.NDArray[Any] = dataclasses.field(
        default_factory=lambda: np.zeros(0, np.float32)
    )
    label: str = ""

    def __post_init__(self) -> None:
        Message.__post_init__(self)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"PointCloud.points must have shape (N, 3), got {self.points.shape}")
        if self.intensity.size and self.intensity.shape != (self.points.shape[0],):
            raise ValueError(
                f"PointCloud.intensity must have shape ({self.points.shape[0]},) or be empty, "
                f"got {self.intensity.shape}"
            )
