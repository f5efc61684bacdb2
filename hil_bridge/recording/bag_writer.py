"""Writing bags (format: :mod:`hil_bridge.recording.bag`): the recorder's MCAP writer, the
JSON export that Foxglove opens, and the recovery of a damaged recording into a finished one.

:class:`BagWriter` keys channels by (topic, type, v, frame_id, src) with one JSON Schema per
message type (:func:`json_schema`); :class:`~hil_bridge.recording.recorder.Recorder` writes the
live bus with it. :func:`export_json` writes a JSON-encoded MCAP (schemas as JSON Schema) of a
bag; :func:`recover` writes everything readable in a damaged bag into a valid, indexed MCAP.
"""

from __future__ import annotations

import json
import typing
from collections.abc import Iterable
from dataclasses import MISSING, fields
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Schema
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from hil_bridge.bus.codec import Header, decode_payload, payload_to_jsonable
from hil_bridge.bus.messages import REGISTRY, Message
from hil_bridge.errors import CodecError, HilError
from hil_bridge.outputs import atomic_output
from hil_bridge.recording.bag import BagInfo, read_bag
from hil_bridge.recording.mcap_scan import ScanReport, scan

__all__ = [
    "COMPRESSIONS",
    "MAX_CHANNELS",
    "MAX_PUBLISHERS_PER_TOPIC",
    "BagWriter",
    "ChannelLimitError",
    "export_json",
    "json_schema",
    "recover",
]

PROFILE = "echoloop"
#: the library named in every bag's header (unchanged when the writer left ``bag.py``: a bag
#: written now is byte for byte what it was)
LIBRARY = "echoloop hil_bridge.recording.bag"
_SEQ_MASK = 0xFFFFFFFF
#: channels per recording (MCAP channel ids are 16 bits); beyond, new channels are refused
MAX_CHANNELS = 60_000
#: publishers (``src``) of one topic, type and frame_id that get a channel of their own
MAX_PUBLISHERS_PER_TOPIC = 64

#: chunk compressions by name (``echoloop bag record --compression``)
COMPRESSIONS = {
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
        if compression not in COMPRESSIONS:
            raise ValueError(
                f"unknown compression {compression!r}; expected one of {sorted(COMPRESSIONS)}"
            )
        self.stream = stream
        self.writer = Writer(stream, chunk_size=chunk_size, compression=COMPRESSIONS[compression])
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

