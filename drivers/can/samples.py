"""Assemble the frames of a glider state sample, never mixing two samples (docs/can.md).

A state sample is GLIDER_STATE_POS, then GLIDER_STATE_QUAT and GLIDER_STATE_RATES when the state
carries an attitude, then GLIDER_STATE_MOTION, which completes it. :class:`SampleAssembler`
turns one node's frames back into :class:`StateSample` values under these rules:

1. Frames that carry the sample counter must agree with the others gathered, modulo the narrower
   field (``state_counter``: all 4 bits in MOTION and RATES, the lowest bit in QUAT; the widths
   are read from the DBC).
2. Frames come in sample order. A frame that cannot follow those gathered (the same kind again,
   an earlier kind, a disagreeing counter) means a frame was lost or belongs to another sample:
   what was gathered is dropped and counted (``samples_torn``), and the frame starts anew.
3. A sample needs its POS and its MOTION, and QUAT and RATES together or neither; otherwise it
   is dropped and counted (``samples_torn``).
4. POS has no bit left for the counter, so it is bound by order: with ``n`` POS frames received
   since the previous MOTION (counter ``c0``), the POS gathered is the sample's own when the
   MOTION's counter is ``c0 + n`` (modulo 16): those ``n`` POS frames were then the ones of the
   ``n`` samples since, in order. When that cannot be shown (the first sample after start, with
   no ``c0``; after a whole sample was lost) the POS might be an older sample's: the sample is
   dropped and counted (``samples_unverified``), and the next one binds again.
5. A frame equal to the node's previous state frame (a CAN duplicate) is ignored and counted
   (``state_frames_duplicate``).

Rule 4 relies on a node's frames arriving in the order they were sent (one transmit queue per
sender, as socketcan and python-can keep); the counters catch what reordering they can reach.
Delivered samples are counted as ``states``. Not thread-safe: one receive thread feeds it (or the
caller holds a lock).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

from drivers.can.codec import DecodedFrame, GliderCanCodec

__all__ = ["COUNTER", "STATE_FRAMES", "SampleAssembler", "StateSample"]

#: The frames of a state sample, in the order they are sent.
STATE_FRAMES = ("GLIDER_STATE_POS", "GLIDER_STATE_QUAT", "GLIDER_STATE_RATES",
                "GLIDER_STATE_MOTION")
#: The sample counter signal.
COUNTER = "state_counter"

_POS, _QUAT, _RATES, _MOTION = STATE_FRAMES
_ORDER = {name: i for i, name in enumerate(STATE_FRAMES)}


@dataclass(frozen=True, slots=True)
class StateSample:
    """One whole state sample of node ``node_id`` (physical values as decoded; ``attitude``
    ``(qw, qx, qy, qz)`` and ``body_rates`` (rad/s) are None for a state sent without them)."""

    node_id: int
    counter: int
    x: float
    y: float
    z: float
    heading: float
    bank: float
    airspeed: float
    vz: float
    alive: bool
    lockstep: bool
    attitude: tuple[float, float, float, float] | None
    body_rates: tuple[float, float, float] | None


@dataclass(slots=True)
class _Node:
    parts: dict[str, Mapping[str, float]] = field(default_factory=dict)
    last_counter: int | None = None
    pos_since: int = 0
    previous: tuple[str, dict[str, float]] | None = None


class SampleAssembler:
    """State frames in, whole :class:`StateSample` values out (rules in the module docstring).

    ``codec`` supplies the DBC the counter widths are read from (default: the profile's).
    """

    def __init__(self, codec: GliderCanCodec | None = None) -> None:
        codec = codec if codec is not None else GliderCanCodec()
        self._bits: dict[str, int] = {}
        for name in STATE_FRAMES:
            spec = next((s for s in codec.signals(name) if s.name == COUNTER), None)
            if spec is not None:
                self._bits[name] = spec.bits
        if _MOTION not in self._bits:
            raise ValueError(f"the DBC's {_MOTION} needs a {COUNTER} signal")
        self._modulus = 1 << self._bits[_MOTION]
        self._nodes: dict[int, _Node] = {}
        self.counters: Counter[str] = Counter()

    def feed(self, frame: DecodedFrame) -> StateSample | None:
        """Take one state frame; the sample it completes, or None."""
        order = _ORDER.get(frame.name)
        if order is None:
            raise ValueError(f"{frame.name} is not a state sample frame; expected {STATE_FRAMES}")
        node = self._nodes.setdefault(frame.node_id, _Node())
        key = (frame.name, dict(frame.signals))
        if key == node.previous:
            self.counters["state_frames_duplicate"] += 1
            return None
        node.previous = key
        if frame.name == _POS:
            node.pos_since += 1
        if node.parts and not self._follows(node.parts, frame, order):
            self.counters["samples_torn"] += 1
            node.parts = {}
        node.parts[frame.name] = frame.signals
        return self._complete(frame.node_id, node) if frame.name == _MOTION else None

    def _follows(self, parts: Mapping[str, Mapping[str, float]], frame: DecodedFrame,
                 order: int) -> bool:
        if max(_ORDER[name] for name in parts) >= order:
            return False
        bits = self._bits.get(frame.name)
        if bits is None:
            return True
        mine = int(frame.signals[COUNTER])
        for name, signals in parts.items():
            other = self._bits.get(name)
            if other is not None and (mine - int(signals[COUNTER])) % (1 << min(bits, other)):
                return False
        return True

    def _complete(self, node_id: int, node: _Node) -> StateSample | None:
        parts, node.parts = node.parts, {}
        counter = int(parts[_MOTION][COUNTER])
        last, pos_since = node.last_counter, node.pos_since
        node.last_counter, node.pos_since = counter, 0
        if _POS not in parts or (_QUAT in parts) != (_RATES in parts):
            self.counters["samples_torn"] += 1
            return None
        if last is None or (counter - last) % self._modulus != pos_since:
            self.counters["samples_unverified"] += 1
            return None
        self.counters["states"] += 1
        pos, motion = parts[_POS], parts[_MOTION]
        quat, rates = parts.get(_QUAT), parts.get(_RATES)
        return StateSample(
            node_id=node_id, counter=counter, x=pos["x_m"], y=pos["y_m"], z=pos["z_m"],
            heading=motion["heading_rad"], bank=motion["bank_rad"],
            airspeed=motion["airspeed_mps"], vz=motion["vz_mps"], alive=bool(motion["alive"]),
            lockstep=bool(pos.get("lockstep", 0)),
            attitude=None if quat is None else (quat["qw"], quat["qx"], quat["qy"], quat["qz"]),
            body_rates=None if rates is None else (
                rates["roll_rate_rps"], rates["pitch_rate_rps"], rates["yaw_rate_rps"]),
        )
