"""Read what can be read of an MCAP file, skipping what is corrupt (as ``mcap recover`` does).

:func:`scan` walks the records of a file from its start, the way a recording is written, and
yields every schema, channel and message it can trust. It never needs the summary section, so
it reads recordings cut short by SIGKILL or power loss, and it never gives up at the first bad
byte:

- a chunk whose CRC, compression or inner records do not check out is skipped whole; the
  message index records that follow it tell how many messages were lost with it (or, when the
  file has a summary, its statistics do);
- bytes that are no record at all (a corrupt length field, garbage) are skipped up to the next
  place where a chunk, schema or channel record checks out completely (a *resync*); so is a
  chunk that does not check out and whose length does not end on a record (its length field
  is what broke), a message index whose lengths disagree, and a footer that is not the last
  record before the closing magic (a broken opcode), so one flipped bit never ends the read
  early or hides what follows;
- a file that ends inside a record is *truncated*: everything before it is read.

What happened is in a :class:`ScanReport`. A file that does not start with the MCAP magic is
refused with :class:`BagFileError` (a ``ValueError`` naming the file).
"""

from __future__ import annotations

import io
import mmap
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Schema
from mcap.records import Message as McapMessage

from hil_bridge.errors import HilError

__all__ = ["MCAP_MAGIC", "BagFileError", "ScanReport", "check_mcap", "scan"]

#: the 8 bytes every MCAP file starts (and a finished one ends) with
MCAP_MAGIC = b"\x89MCAP0\r\n"

_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
_STATISTICS, _DATA_END = 0x0B, 0x0F
_KNOWN_OPS = frozenset(range(0x01, 0x10))
_U64 = struct.Struct("<Q")
_U32 = struct.Struct("<I")
_U16 = struct.Struct("<H")
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_COMPRESSIONS = ("", "zstd", "lz4")
_MAX_ERRORS = 20

Item = Schema | Channel | McapMessage


class BagFileError(HilError, ValueError):
    """A file is not an MCAP recording at all."""


@dataclass
class ScanReport:
    """What :func:`scan` found in one file (counts of what it read and what it skipped)."""

    path: str
    profile: str = ""
    messages: int = 0
    chunks: int = 0
    corrupt_chunks: int = 0
    #: messages in skipped chunks, as counted by their message indexes
    lost_messages: int = 0
    #: skipped chunks whose message count is unknown (their index was lost too)
    unknown_loss_chunks: int = 0
    #: messages whose channel record was never found
    orphans: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0
    #: the file ends before its footer (a writer killed, a copy cut short)
    truncated: bool = False
    #: bytes after the last complete record of a truncated file
    tail_bytes: int = 0
    #: the file ends with a summary and footer (it was closed properly)
    finished: bool = False
    #: the message count the file's own statistics record states, if any
    stated_messages: int | None = None
    errors: list[str] = field(default_factory=list)

    @property
    def lost(self) -> int:
        """Messages known to be lost (the file's statistics, when present, are exact)."""
        if self.stated_messages is not None:
            return max(0, self.stated_messages - self.messages)
        return self.lost_messages + self.orphans

    @property
    def damaged(self) -> bool:
        return bool(self.corrupt_chunks or self.resyncs or self.orphans or self.truncated
                    or self.lost)

    def note(self, offset: int, what: str) -> None:
        if len(self.errors) < _MAX_ERRORS:
            self.errors.append(f"offset {offset}: {what}")

    def describe(self) -> str:
        """One line: what was kept and what was lost."""
        parts = [f"{self.messages} messages read"]
        if self.corrupt_chunks:
            unknown = (f", {self.unknown_loss_chunks} of them of unknown size"
                       if self.unknown_loss_chunks else "")
            parts.append(f"{self.corrupt_chunks} corrupt chunk(s) skipped{unknown}")
        if self.resyncs:
            parts.append(f"{self.skipped_bytes} unreadable bytes skipped")
        if self.orphans:
            parts.append(f"{self.orphans} messages of unknown channels dropped")
        if self.truncated:
            parts.append("file cut short" + (f" ({self.tail_bytes} bytes of a partial record)"
                                             if self.tail_bytes else " (no summary)"))
        parts.append(f"{self.lost} messages lost"
                     + (" (at least)" if self.stated_messages is None and self.damaged else ""))
        return ", ".join(parts)


def _string(buf: memoryview, pos: int, end: int) -> tuple[str, int] | None:
    if pos + 4 > end:
        return None
    (n,) = _U32.unpack_from(buf, pos)
    if pos + 4 + n > end:
        return None
    try:
        return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n
    except UnicodeDecodeError:
        return None


def _chunk_parts(buf: memoryview, pos: int, end: int) -> tuple[str, int, int, int, int] | None:
    """(compression, uncompressed size, crc, data start, data end) of a chunk record whose
    content spans ``pos:end``, if its fields are consistent; else None."""
    if pos + _CHUNK_HEAD.size > end:
        return None
    _, _, size, crc = _CHUNK_HEAD.unpack_from(buf, pos)
    got = _string(buf, pos + _CHUNK_HEAD.size, end)
    if got is None or got[0] not in _COMPRESSIONS:
        return None
    compression, p = got
    if p + 8 > end:
        return None
    (n,) = _U64.unpack_from(buf, p)
    if p + 8 + n != end or size > 1 << 34:
        return None
    return compression, size, crc, p + 8, end


def _parse(record: type[Schema] | type[Channel], content: bytes) -> Schema | Channel | None:
    stream = ReadDataStream(io.BytesIO(content))
    try:
        parsed = record.read(stream)
    except Exception:  # a corrupt record: mcap raises struct, Unicode and its own errors
        return None
    return parsed if stream.count == len(content) else None


def _plausible(buf: memoryview, pos: int, n: int) -> bool:
    """Whether a whole chunk, schema or channel record that checks out starts at ``pos``."""
    if pos + 9 > n:
        return False
    op, length = _REC.unpack_from(buf, pos)
    end = pos + 9 + length
    if end > n:
        return False
    if op == _CHUNK:
        return _chunk_parts(buf, pos + 9, end) is not None
    if op in (_SCHEMA, _CHANNEL) and length < 1 << 20:
        return _parse(Schema if op == _SCHEMA else Channel, bytes(buf[pos + 9:end])) is not None
    return False


def _resync(buf: memoryview, raw: mmap.mmap, pos: int, n: int) -> int:
    """The first offset after ``pos`` where :func:`_plausible` holds, else ``n``."""
    starts = {op: raw.find(bytes([op]), pos + 1) for op in (_CHUNK, _SCHEMA, _CHANNEL)}
    while True:
        live = {op: p for op, p in starts.items() if p >= 0}
        if not live:
            return n
        op, p = min(live.items(), key=lambda kv: kv[1])
        if _plausible(buf, p, n):
            return p
        starts[op] = raw.find(bytes([op]), p + 1)


def _index_ok(buf: memoryview, pos: int, length: int) -> bool:
    """Whether the message index record at ``pos`` is well formed (its lengths agree)."""
    return length >= 6 and (length - 6) % 16 == 0 and (
        _U32.unpack_from(buf, pos + 9 + 2)[0] == length - 6)


def _last(buf: memoryview, end: int, n: int) -> bool:
    """Whether a record ending at ``end`` is followed by the closing magic and nothing else."""
    return end + len(MCAP_MAGIC) == n and bytes(buf[end:n]) == MCAP_MAGIC


def _broken(op: int, buf: memoryview, pos: int, end: int, n: int) -> bool:
    """Whether a record of a known opcode at ``pos``, inside the file, cannot be trusted to end
    at ``end``: a malformed message index, a footer that is not the last record, or a chunk
    that does not check out and whose length ends on no record."""
    if op == _MESSAGE_INDEX:
        return not _index_ok(buf, pos, end - pos - 9)
    if op == _FOOTER:
        return not _last(buf, end, n)
    return (op == _CHUNK and _chunk_parts(buf, pos + 9, end) is None
            and not _boundary(buf, end, n))


def _boundary(buf: memoryview, end: int, n: int) -> bool:
    """Whether a record can start at ``end`` (the file's end, the closing magic, a well-formed
    message index, or a chunk, schema or channel that checks out)."""
    if end == n or _last(buf, end, n) or _plausible(buf, end, n):
        return True
    if end + 9 > n:
        return False
    op, length = _REC.unpack_from(buf, end)
    return op == _MESSAGE_INDEX and end + 9 + length <= n and _index_ok(buf, end, length)


def _chunk_records(data: bytes) -> list[Item]:
    """The schema, channel and message records of one decompressed chunk (ValueError if any
    record is malformed)."""
    out: list[Item] = []
    view = memoryview(data)
    pos, n = 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise ValueError("partial record at the end of the chunk")
        op, length = _REC.unpack_from(view, pos)
        start, end = pos + 9, pos + 9 + length
        if end > n:
            raise ValueError(f"record of {length} bytes overruns the chunk")
        if op == _MESSAGE:
            if length < _MSG.size:
                raise ValueError("message record too short")
            cid, seq, log_time, pub_time = _MSG.unpack_from(view, start)
            out.append(McapMessage(channel_id=cid, sequence=seq, log_time=log_time,
                                   publish_time=pub_time,
                                   data=bytes(view[start + _MSG.size:end])))
        elif op in (_SCHEMA, _CHANNEL):
            rec = _parse(Schema if op == _SCHEMA else Channel, bytes(view[start:end]))
            if rec is None:
                raise ValueError(f"malformed {'schema' if op == _SCHEMA else 'channel'} record")
            out.append(rec)
        pos = end
    return out


def _decompress(compression: str, payload: bytes, size: int) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-untyped]

        data: bytes = lz4.frame.decompress(payload)
        return data
    return payload


def check_mcap(path: str | Path) -> None:
    """Raise :class:`BagFileError` unless ``path`` starts with the MCAP magic (or OSError)."""
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise BagFileError(f"{path}: not an MCAP file (starts with {head[:8]!r})")


def scan(path: str | Path, report: ScanReport | None = None) -> Iterator[Item]:
    """Yield the schemas, channels and messages of ``path`` in file order (module docstring).

    A schema or channel is yielded when its id first appears and again for each copy inside a
    chunk (those are CRC-checked: the latest copy of an id is the one to use); messages are
    yielded only after their channel (others are counted as ``orphans``). Fills ``report``.
    """
    report = report if report is not None else ScanReport(str(path))
    check_mcap(path)
    with open(path, "rb") as f:
        size = f.seek(0, io.SEEK_END)
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as raw:
            yield from _walk(memoryview(raw), raw, size, report)


class _LossCount:
    """Messages lost with skipped chunks, from the message index records that follow each."""

    def __init__(self, report: ScanReport) -> None:
        self.report = report
        self.open = False
        self.indexed = False
        self.entries = 0

    def bad_chunk(self) -> None:
        self.close()
        self.report.corrupt_chunks += 1
        self.open, self.indexed, self.entries = True, False, 0

    def index(self, entries: int) -> None:
        if self.open:
            self.indexed = True
            self.entries += entries

    def close(self) -> None:
        if self.open:
            if self.indexed:
                self.report.lost_messages += self.entries
            else:
                self.report.unknown_loss_chunks += 1
            self.open = False


def _walk(buf: memoryview, raw: mmap.mmap, n: int, report: ScanReport) -> Iterator[Item]:
    channels: set[int] = set()
    schemas: set[int] = set()
    loss = _LossCount(report)
    pos = len(MCAP_MAGIC)
    try:
        while pos < n:
            if pos + 9 > n:
                report.truncated, report.tail_bytes = True, n - pos
                return
            op, length = _REC.unpack_from(buf, pos)
            start, end = pos + 9, pos + 9 + length
            if op not in _KNOWN_OPS or end > n or _broken(op, buf, pos, end, n):
                nxt = _resync(buf, raw, pos, n)
                if nxt >= n and op in _KNOWN_OPS and end > n:
                    report.truncated, report.tail_bytes = True, n - pos
                    return
                if op == _CHUNK and end <= n:
                    loss.bad_chunk()
                loss.close()
                report.note(pos, f"unreadable bytes (opcode {op:#04x}, length {length})")
                report.resyncs += 1
                report.skipped_bytes += nxt - pos
                pos = nxt
                continue
            if op == _MESSAGE_INDEX:
                loss.index(_U32.unpack_from(buf, start + 2)[0] // 16)
                pos = end
                continue
            loss.close()
            if op == _CHUNK:
                items = _read_chunk(buf, start, end, pos, report)
                if items is None:
                    loss.bad_chunk()
                else:
                    report.chunks += 1
                    for item in items:
                        yield from _emit(item, channels, schemas, report, verified=True)
            elif op in (_SCHEMA, _CHANNEL, _MESSAGE):
                record = _top_level(op, buf, start, end)
                if record is None:
                    report.note(pos, "malformed record skipped")
                    report.resyncs += 1
                    report.skipped_bytes += end - pos
                else:
                    yield from _emit(record, channels, schemas, report, verified=False)
            elif op == _HEADER:
                got = _string(buf, start, end)
                report.profile = got[0] if got is not None else ""
            elif op == _STATISTICS and length >= 8:
                (report.stated_messages,) = _U64.unpack_from(buf, start)
            elif op == _FOOTER:
                report.finished = True
                return
            pos = end
        report.truncated = True  # the data ends without a footer: the writer never finished
    finally:
        loss.close()


def _read_chunk(buf: memoryview, start: int, end: int, pos: int,
                report: ScanReport) -> list[Item] | None:
    parts = _chunk_parts(buf, start, end)
    if parts is None:
        report.note(pos, "chunk header does not check out")
        return None
    compression, size, crc, data_start, data_end = parts
    try:
        data = _decompress(compression, bytes(buf[data_start:data_end]), size)
    except Exception as exc:  # zstd/lz4 raise their own error types on corrupt input
        report.note(pos, f"chunk does not decompress ({type(exc).__name__}: {exc})")
        return None
    if len(data) != size or (crc and zlib.crc32(data) != crc):
        report.note(pos, "chunk CRC mismatch")
        return None
    try:
        return _chunk_records(data)
    except (ValueError, struct.error) as exc:
        report.note(pos, f"chunk records do not parse ({exc})")
        return None


def _top_level(op: int, buf: memoryview, start: int, end: int) -> Item | None:
    if op == _MESSAGE:
        if end - start < _MSG.size:
            return None
        cid, seq, log_time, pub_time = _MSG.unpack_from(buf, start)
        return McapMessage(channel_id=cid, sequence=seq, log_time=log_time,
                           publish_time=pub_time, data=bytes(buf[start + _MSG.size:end]))
    return _parse(Schema if op == _SCHEMA else Channel, bytes(buf[start:end]))


def _emit(item: Item, channels: set[int], schemas: set[int], report: ScanReport, *,
          verified: bool) -> Iterator[Item]:
    """Messages of known channels; schema and channel records when new, or again when a copy
    from a chunk (CRC-checked) arrives after an unchecked one outside the chunks."""
    if isinstance(item, McapMessage):
        if item.channel_id in channels:
            report.messages += 1
            yield item
        else:
            report.orphans += 1
        return
    known = channels if isinstance(item, Channel) else schemas
    if verified or item.id not in known:
        known.add(item.id)
        yield item
