"""Recording and replay of the bus in MCAP files (the ``mcap`` library).

Bag format (what ``echoloop bag record`` writes):

- One MCAP **channel** per (topic, message type, version, frame_id, publisher ``src``); channel
  metadata holds ``type``, ``v``, ``frame_id`` and ``src``; ``message_encoding`` is ``msgpack``.
- One **schema** per message type: name = the type (``echoloop/GliderState``), encoding
  ``jsonschema``, data = a JSON Schema of the msgpack payload map (arrays are maps
  ``{dtype, shape, data}``).
- Each **message** holds the payload frame *byte for byte*; ``log_time`` = receive time (ns,
  Unix epoch, steady), ``publish_time`` = header ``stamp_ns`` (sim time), ``sequence`` =
  header ``seq`` (MCAP keeps 32 bits: seq wraps after 2³² messages of one publisher).
- Small chunks (64 KiB by default) and a chunk flush at least every ``flush_period_s`` (1 s), so
  a recorder killed without warning (SIGKILL, power loss) leaves a file readable up to its last
  complete chunk; :func:`read_bag` reads such truncated files and reports ``truncated``.

Replay (:class:`Player`) re-publishes each message with its recorded header (type, v, seq,
stamp_ns, frame_id, src) and payload, a fresh ``pub_ns``, paced by ``log_time`` / ``rate``: a
recording of a replay has byte-identical payloads and identical seq and stamps. ``export_json``
writes a JSON-encoded MCAP (schemas as JSON Schema) that Foxglove opens.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
import typing
from collections.abc import Iterable, Iterator
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Schema
from mcap.records import Message as McapMessage
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from hil_bridge.bus.codec import (
    Header,
    decode_payload,
    encode,
    pack_header,
    payload_to_jsonable,
    topic_frame,
    validate_topic,
)
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.messages import REGISTRY, Clock, Message
from hil_bridge.bus.stats import TopicStats
from hil_bridge.bus.transport import Transport, open_transport
from hil_bridge.errors import CodecError, HilError
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.mcap_scan import ScanReport, check_mcap, scan

__all__ = [
    "MAX_CHANNELS",
    "MAX_PUBLISHERS_PER_TOPIC",
    "BagInfo",
    "BagMessage",
    "BagWriter",
    "ChannelLimitError",
    "Player",
    "bag_info",
    "export_json",
    "json_schema",
    "read_bag",
    "recover",
]

log = logging.getLogger(__name__)

PROFILE = "echoloop"
LIBRARY = "echoloop hil_bridge.recording.bag"
_SEQ_MASK = 0xFFFFFFFF
#: channels per recording (MCAP channel ids are 16 bits); beyond, new channels are refused
MAX_CHANNELS = 60_000
#: publishers (``src``) of one topic, type and frame_id that get a channel of their own
MAX_PUBLISHERS_PER_TOPIC = 64

_COMPRESSION = {
    "none": CompressionType.NONE,
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
}


def _field_schema(hint: Any, array: bool, *, as_json: bool) -> dict[str, Any]:
    if array:
        if as_json:
            return {"type": "array", "description": "nested lists, C order"}
        return {
            "type": "object",
            "properties": {
                "dtype": {"type": "string"},
                "shape": {"type": "array", "items": {"type": "integer"}},
                "data": {"type": "string", "contentEncoding": "binary"},
            },
            "required": ["dtype", "shape", "data"],
        }
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"type": ["number", "null"]} if as_json else {"type": "number"}
    if hint is str:
        return {"type": "string"}
    return {"type": "object", "additionalProperties": {"type": ["number", "null"]}}


def json_schema(cls: type[Message], *, as_json: bool = False) -> dict[str, Any]:
    """JSON Schema of ``cls``'s payload: the msgpack map, or (``as_json``) its JSON export."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": cls.TYPE,
        "description": (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else "",
        "type": "object",
        "properties": {
            n: _field_schema(hints[n], n in cls.ARRAYS, as_json=as_json) for n in names
        },
        "required": [
            f.name
            for f in fields(cls)  # type: ignore[arg-type]
            if f.default is MISSING and f.default_factory is MISSING
        ],
        "x-echoloop-version": cls.VERSION,
    }


def _schema_bytes(type_name: str, *, as_json: bool = False) -> bytes:
    cls = REGISTRY.get(type_name)
    schema = json_schema(cls, as_json=as_json) if cls is not None else {"type": "object"}
    return json.dumps(schema, sort_keys=True).encode()


@dataclass(frozen=True, slots=True)
class BagMessage:
    """One recorded message: topic, the header to re-send, the payload frame, and times."""

    topic: str
    header: Header
    payload: bytes
    log_time: int
    channel_id: int


@dataclass
class BagInfo:
    """Summary of a bag (``echoloop bag info``); ``scan`` says what was skipped as corrupt."""

    path: str
    messages: int = 0
    truncated: bool = False
    error: str = ""
    start_ns: int | None = None
    end_ns: int | None = None
    channels: int = 0
    topics: dict[str, TopicStats] = field(default_factory=dict)
    #: messages on channels whose topic is not a bus topic name (not read)
    skipped: int = 0
    scan: ScanReport | None = None

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def damaged(self) -> bool:
        """Corrupt chunks or bytes were skipped, or the file was cut short."""
        return self.scan is not None and self.scan.damaged

    def as_dict(self) -> dict[str, Any]:
        scan = self.scan
        return {
            "path": self.path,
            "messages": self.messages,
            "channels": self.channels,
            "truncated": self.truncated,
            "finished": bool(scan and scan.finished),
            "corrupt_chunks": scan.corrupt_chunks if scan else 0,
            "lost_messages": scan.lost if scan else 0,
            "skipped": self.skipped,
            "error": self.error,
            "duration_s": self.duration_s,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "topics": {t: s.as_dict() for t, s in sorted(self.topics.items())},
        }


def _header_of(channel: Channel, msg: McapMessage) -> Header:
    meta = channel.metadata
    try:
        version = int(meta.get("v", "1"))
    except ValueError:
        version = 1
    return Header(
        type=meta.get("type", ""),
        v=version,
        seq=msg.sequence,
        stamp_ns=msg.publish_time,
        pub_ns=0,
        frame_id=meta.get("frame_id", ""),
        src=meta.get("src", ""),
    )


def read_bag(
    path: str | Path, topics: Iterable[str] | None = None, *, info: BagInfo | None = None
) -> Iterator[BagMessage]:
    """Recorded messages in file (= receive) order, optionally only ``topics``.

    Reads with :func:`hil_bridge.recording.mcap_scan.scan`: a truncated file yields every message
    of its
    complete chunks, a corrupt chunk is skipped and the rest read. Pass ``info`` to learn what
    was skipped (``info.scan``, ``info.truncated``, ``info.error``).
    """
    wanted = None if topics is None else set(topics)
    report = ScanReport(str(path))
    channels: dict[int, Channel | None] = {}
    for record in scan(path, report):
        if isinstance(record, Channel):
            channels[record.id] = record if _is_topic(record.topic) else None
        elif isinstance(record, McapMessage):
            channel = channels.get(record.channel_id)
            if channel is None:
                if info is not None:
                    info.skipped += 1
                continue
            if wanted is not None and channel.topic not in wanted:
                continue
            yield BagMessage(channel.topic, _header_of(channel, record), record.data,
                             record.log_time, channel.id)
    if info is not None:
        info.scan = report
        info.truncated = report.truncated
        info.error = "; ".join(report.errors[:3])
        info.channels = len(channels)


def _is_topic(name: str) -> bool:
    try:
        validate_topic(name)
    except ValueError:
        return False
    return True


def bag_info(path: str | Path) -> BagInfo:
    """Counts, rates, seq gaps and time span per topic; ``truncated`` if the file is cut."""
    info = BagInfo(str(path))
    for m in read_bag(path, info=info):
        stats = info.topics.get(m.topic)
        if stats is None:
            stats = info.topics[m.topic] = TopicStats(m.topic)
        stats.add(m.header, len(m.payload), m.log_time)
        info.messages += 1
        info.start_ns = m.log_time if info.start_ns is None else min(info.start_ns, m.log_time)
        info.end_ns = m.log_time if info.end_ns is None else max(info.end_ns, m.log_time)
    return info


class ChannelLimitError(HilError):
    """A recording reached :data:`MAX_CHANNELS` channels; messages of new channels are lost."""


class BagWriter:
    """MCAP writer keyed by channel (topic, type, v, frame_id, src) with one schema per type.

    At most :data:`MAX_PUBLISHERS_PER_TOPIC` publishers of one (topic, type, v, frame_id) get a
    channel of their own; later ones share a channel whose ``src`` is empty (counted in
    ``src_shared``), so unbounded distinct ``src`` values cost no more channels. Every schema
    and channel record is also written outside the chunks when it is made: a recovery reader
    knows every channel even when the chunk that first used it is corrupt.
    """

    def __init__(
        self,
        stream: IO[bytes],
        *,
        chunk_size: int,
        compression: str,
        message_encoding: str,
        as_json: bool,
        max_channels: int = MAX_CHANNELS,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(
                f"unknown compression {compression!r}; expected one of {sorted(_COMPRESSION)}"
            )
        self.stream = stream
        self.writer = Writer(stream, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self.writer.start(profile=PROFILE, library=LIBRARY)
        self.encoding = message_encoding
        self.as_json = as_json
        self.max_channels = max_channels
        self.schemas: dict[str, int] = {}
        self.channels: dict[tuple[str, str, int, str, str], int] = {}
        self.publishers: dict[tuple[str, str, int, str], int] = {}
        self.src_shared = 0

    def _outside_chunks(self, record: Schema | Channel) -> None:
        # between two calls the Writer has flushed everything but the open chunk to the
        # stream, so a record appended here lands in the data section, before that chunk
        builder = RecordBuilder()
        record.write(builder)
        self.stream.write(builder.end())

    def channel(self, topic: str, header: Header) -> int:
        """The channel id of ``header`` on ``topic`` (``ChannelLimitError`` past the limit)."""
        key = (topic, header.type, header.v, header.frame_id, header.src)
        cid = self.channels.get(key)
        if cid is not None:
            return cid
        base = key[:4]
        shared = self.publishers.get(base, 0) >= MAX_PUBLISHERS_PER_TOPIC
        if shared:
            self.src_shared += 1
            key = (*base, "")
            cid = self.channels.get(key)
            if cid is not None:
                return cid
        if len(self.channels) >= self.max_channels:
            raise ChannelLimitError(
                f"{len(self.channels)} channels (the limit): messages of new (topic, type, "
                f"frame_id) combinations are not recorded, e.g. {topic!r}"
            )
        sid = self.schemas.get(header.type)
        if sid is None:
            data = _schema_bytes(header.type, as_json=self.as_json)
            sid = self.writer.register_schema(
                name=header.type, encoding=SchemaEncoding.JSONSchema, data=data
            )
            self.schemas[header.type] = sid
            self._outside_chunks(Schema(id=sid, name=header.type,
                                        encoding=SchemaEncoding.JSONSchema, data=data))
        metadata = {"type": header.type, "v": str(header.v), "frame_id": header.frame_id,
                    "src": key[4]}
        if shared:
            metadata["src_shared"] = "true"
        cid = self.writer.register_channel(
            topic=topic, message_encoding=self.encoding, schema_id=sid, metadata=metadata
        )
        self._outside_chunks(Channel(id=cid, topic=topic, message_encoding=self.encoding,
                                     schema_id=sid, metadata=metadata))
        self.channels[key] = cid
        if not shared:
            self.publishers[base] = self.publishers.get(base, 0) + 1
        return cid

    def add(self, topic: str, header: Header, data: bytes, log_time: int) -> None:
        self.writer.add_message(
            channel_id=self.channel(topic, header),
            log_time=log_time,
            data=data,
            publish_time=max(0, header.stamp_ns),
            sequence=header.seq & _SEQ_MASK,
        )


class Player:
    """Re-publish a bag on the bus (launchable-like: ``start()``, ``stop()``, ``stats()``).

    ``Player(path, *, bus=None, rate=1.0, loop=False, start_offset_s=0.0, topics=None,
    clock=False, clock_hz=100.0, wait_for_subscribers_s=0.0)``. ``rate`` scales the recorded
    receive timing (``math.inf``: as fast as possible). ``loop`` repeats (each pass re-sends
    under ``src`` suffixed ``~loopK`` so receivers do not drop it as duplicates). ``clock``
    publishes ``/clock`` from the recorded stamps (at most ``clock_hz`` per wall second) and
    leaves out recorded ``/clock``. ``wait_for_subscribers_s`` > 0 first waits (up to that long)
    until every played topic has a subscriber. :meth:`wait` blocks until playback ends.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        bus: str | None = None,
        rate: float = 1.0,
        loop: bool = False,
        start_offset_s: float = 0.0,
        topics: Iterable[str] | None = None,
        clock: bool = False,
        clock_hz: float = 100.0,
        wait_for_subscribers_s: float = 0.0,
        name: str = "player",
    ) -> None:
        if not (isinstance(rate, (int, float)) and rate > 0):
            raise ValueError(f"rate must be > 0 (math.inf: as fast as possible), got {rate!r}")
        if start_offset_s < 0:
            raise ValueError(f"start_offset_s must be >= 0, got {start_offset_s}")
        if not clock_hz > 0:
            raise ValueError(f"clock_hz must be > 0, got {clock_hz}")
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"bag {str(self.path)!r} does not exist")
        check_mcap(self.path)
        self.bus = bus if bus is not None else current_domain().bus_url
        self.rate = float(rate)
        self.loop = loop
        self.start_offset_s = start_offset_s
        self.topics = None if topics is None else [validate_topic(t) for t in topics]
        self.clock = clock
        self.clock_hz = clock_hz
        self.wait_for_subscribers_s = wait_for_subscribers_s
        self.name = name
        self._stop = threading.Event()
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._transport: Transport | None = None
        self._stopped = False
        self._counters = {"published": 0, "passes": 0, "clock_published": 0}
        self.truncated = False
        #: what the last pass read (corrupt chunks skipped, truncation)
        self.info: BagInfo | None = None
        self.error: BaseException | None = None

    def start(self) -> Player:
        with self._lock:
            if self._thread is not None or self._stopped:
                return self
            self._transport = open_transport(self.bus)
            self._thread = threading.Thread(
                target=self._run, args=(self._transport,), name=f"{self.name}-play", daemon=True
            )
            self._thread.start()
        return self

    def _played_topics(self) -> list[str]:
        topics = {m.topic for m in read_bag(self.path, self.topics)}
        if self.clock:
            topics.discard("/clock")
            topics.add("/clock")
        return sorted(topics)

    def _run(self, transport: Transport) -> None:
        try:
            if self.wait_for_subscribers_s > 0:
                deadline = time.monotonic() + self.wait_for_subscribers_s
                for topic in self._played_topics():
                    transport.wait_for_subscriber(topic, max(0.0, deadline - time.monotonic()))
            clock_seq = 0
            passes = 0
            while not self._stop.is_set():
                clock_seq = self._play_once(transport, passes, clock_seq)
                passes += 1
                self._counters["passes"] = passes
                if not self.loop:
                    break
        except BaseException as exc:
            self.error = exc
            raise
        finally:
            self._done.set()

    def _play_once(self, transport: Transport, passes: int, clock_seq: int) -> int:
        info = BagInfo(str(self.path))
        first_log: int | None = None
        wall0 = time.monotonic()
        clock_period = 1.0 / self.clock_hz
        next_clock = 0.0
        last_clock_stamp = -1
        suffix = f"~loop{passes}" if passes else ""
        for m in read_bag(self.path, self.topics, info=info):
            if self._stop.is_set():
                break
            if first_log is None:
                first_log = m.log_time
            offset_s = (m.log_time - first_log) / 1e9
            if offset_s < self.start_offset_s:
                continue
            if self.clock and m.topic == "/clock":
                continue
            if math.isfinite(self.rate):
                due = wall0 + (offset_s - self.start_offset_s) / self.rate
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
            now = time.monotonic()
            if self.clock and m.header.stamp_ns > last_clock_stamp and now >= next_clock:
                clock_msg = Clock(stamp_ns=m.header.stamp_ns)
                transport.publish(encode("/clock", clock_msg, seq=clock_seq,
                                         pub_ns=time.monotonic_ns(), src=f"{self.name}/clock"))
                clock_seq += 1
                last_clock_stamp = m.header.stamp_ns
                next_clock = now + clock_period
                self._counters["clock_published"] += 1
            header = Header(m.header.type, m.header.v, m.header.seq, m.header.stamp_ns,
                            time.monotonic_ns(), m.header.frame_id, m.header.src + suffix)
            transport.publish([topic_frame(m.topic), pack_header(header), m.payload])
            self._counters["published"] += 1
        self.truncated = self.truncated or info.truncated
        self.info = info
        return clock_seq

    def wait(self, timeout: float | None = None) -> bool:
        """True once playback ended (end of bag, or stop); False after ``timeout`` s."""
        return self._done.wait(timeout)

    def stop(self) -> None:
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            thread, transport = self._thread, self._transport
        self._stop.set()
        if thread is not None:
            thread.join()
        if transport is not None:
            transport.close()

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self._counters)
        out["truncated"] = self.truncated
        return out


def export_json(
    src: str | Path, dst: str | Path, *, topics: Iterable[str] | None = None,
    info: BagInfo | None = None,
) -> dict[str, int]:
    """Write ``dst``: a JSON-encoded MCAP (JSON Schemas) of ``src`` that Foxglove can open.

    Arrays become nested lists, non-finite floats ``null``. Messages of unknown types or newer
    versions are skipped and counted; corrupt chunks of ``src`` are skipped (``info.scan``).
    Returns ``{"messages", "skipped"}``.
    """
    counts = {"messages": 0, "skipped": 0}
    with open(dst, "wb") as stream:
        bag = BagWriter(stream, chunk_size=1024 * 1024, compression="zstd",
                         message_encoding=MessageEncoding.JSON, as_json=True)
        for m in read_bag(src, topics, info=info):
            try:
                msg = decode_payload(m.header.type, m.header.v, m.payload)
            except CodecError:
                counts["skipped"] += 1
                continue
            data = json.dumps(payload_to_jsonable(msg), allow_nan=False).encode()
            bag.add(m.topic, m.header, data, m.log_time)
            counts["messages"] += 1
        bag.writer.finish()
    return counts


def recover(
    src: str | Path, dst: str | Path, *, overwrite: bool = False, chunk_size: int = 1 << 20,
) -> ScanReport:
    """Write ``dst``: a valid, indexed MCAP (summary, chunk and message indexes) of everything
    readable in ``src`` — a recording cut short, killed, or with corrupt chunks.

    Schemas and channels keep their content (ids may be renumbered); messages keep their
    data, times and sequence, in file order. Returns the :class:`ScanReport` of ``src``
    (``messages`` kept, ``lost``, what was skipped). ``dst`` goes through
    :class:`~hil_bridge.outputs.AtomicOutput` (never ``src``, never an existing file unless
    ``overwrite``).
    """
    report = ScanReport(str(src))
    with atomic_output(dst, overwrite=overwrite, inputs=[src]) as tmp, open(tmp, "wb") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for record in scan(src, report):
            if not started:
                writer.start(profile=report.profile or PROFILE, library=LIBRARY)
                started = True
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            else:
                cid = channel_ids.get(record.channel_id)
                if cid is None:
                    channel = channels[record.channel_id]
                    sid = 0
                    schema = schemas.get(channel.schema_id)
                    if schema is not None:
                        sid = schema_ids.get(schema.id, 0)
                        if not sid:
                            sid = schema_ids[schema.id] = writer.register_schema(
                                name=schema.name, encoding=schema.encoding, data=schema.data)
                    cid = channel_ids[record.channel_id] = writer.register_channel(
                        topic=channel.topic, message_encoding=channel.message_encoding,
                        schema_id=sid, metadata=dict(channel.metadata))
                writer.add_message(channel_id=cid, log_time=record.log_time, data=record.data,
                                   publish_time=record.publish_time, sequence=record.sequence)
        if not started:
            writer.start(profile=report.profile or PROFILE, library=LIBRARY)
        writer.finish()
    return report


def __getattr__(name: str) -> Any:
    """``hil_bridge.recording.bag.Recorder`` still works; the recorder lives in
    :mod:`hil_bridge.recording.recorder`."""
    if name == "Recorder":
        from hil_bridge.recording.recorder import Recorder

        return Recorder
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
