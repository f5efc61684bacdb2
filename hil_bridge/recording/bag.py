"""Bags: the MCAP recordings of the bus, their format, and reading them.

Bag format (what ``echoloop bag record`` writes, :mod:`hil_bridge.recording.bag_writer`):

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

Here: :func:`read_bag` (the messages of a bag, damaged or not), :func:`bag_info` (``echoloop bag
info``) and their records :class:`BagMessage`, :class:`BagInfo`. Writing, the JSON export and
recovery are in :mod:`hil_bridge.recording.bag_writer`, replay onto the bus in
:mod:`hil_bridge.recording.bag_player`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.records import Channel
from mcap.records import Message as McapMessage

from hil_bridge.bus.codec import Header, validate_topic
from hil_bridge.bus.stats import TopicStats
from hil_bridge.recording.mcap_scan import ScanReport, scan

__all__ = ["BagInfo", "BagMessage", "bag_info", "read_bag"]


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

