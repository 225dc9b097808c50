"""
The MCAP record layer that reading and repairing share.

Framing checks, chunk recovery, the header's format version, and the records of a file front to
back (never the index, never a length it cannot verify). The reader decodes messages on top of it;
repair rewrites what it yields.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import io
import os
from pathlib import Path
import re
import struct
from typing import Any, Iterator, NamedTuple
import zlib

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
)
from mcap.stream_reader import breakup_chunk

MCAP_MAGIC = b'\x89MCAP0\r\n'
MCAP_MAGIC_PREFIX = b'\x89MCAP'
FORMAT_VERSION = 1  # pulsejet recording format this reader understands (and the writer writes)
_FORMAT_RE = re.compile(r'pulsejet-format=(\d+)')
MAX_CHUNK_UNCOMPRESSED = (
    1 << 30
)  # a chunk claiming more is corrupt (the writer's chunks are ~256 KiB)
_KNOWN_OPCODES = frozenset(int(o) for o in Opcode)


class BagReadError(ValueError):
    """
    A file that is missing, not an MCAP, or not a ROS 2 (profile `ros2`) recording.

    The message names the file.
    """


class BagMessage(NamedTuple):
    topic: str  # qualified name as stored, e.g. '/pulsejet/velocity'
    type_name: str  # e.g. 'geometry_msgs/msg/TwistStamped'
    log_time_ns: int  # receive time (recorder) or simulation time (offline runner), ns
    msg: Any  # decoded message (attribute access like the rclpy class)


@dataclass
class BagInfo:
    """What a full read of the file found."""

    path: Path
    profile: str = ''
    library: str = ''  # MCAP header library field
    topics: dict[str, str] = field(default_factory=dict)  # topic -> type name
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages
    definitions: dict[str, str] = field(default_factory=dict)  # type name -> ros2msg text
    channel_metadata: dict[str, dict[str, str]] = field(
        default_factory=dict
    )  # topic -> channel metadata
    encodings: dict[str, str] = field(default_factory=dict)  # topic -> message encoding
    schema_encodings: dict[str, str] = field(default_factory=dict)  # type name -> schema encoding
    metadata: list[tuple[str, dict[str, str]]] = field(
        default_factory=list
    )  # MCAP metadata records
    attachments: list[Attachment] = field(default_factory=list)
    truncated: bool = False  # no footer: writer killed hard (or cut)
    file_size: int = 0  # bytes
    valid_bytes: int = 0  # end of the last record read intact
    bytes_dropped: int = 0  # bytes that could not be read
    corrupt_chunks: int = 0  # chunks skipped (CRC, decompression)
    undecodable: dict[str, int] = field(
        default_factory=dict
    )  # topic -> messages that failed to decode
    orphan_messages: int = 0  # messages whose channel record was lost
    first_log_ns: int | None = None
    last_log_ns: int | None = None
    stop_reason: str = ''  # why reading stopped before a footer

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    @property
    def damaged(self) -> bool:
        return bool(
            self.truncated
            or self.bytes_dropped
            or self.corrupt_chunks
            or self.undecodable
            or self.orphan_messages
        )

    def damage_report(self) -> str:
        """One paragraph saying what was recovered and what was cut ('' for an intact file)."""
        if not self.damaged:
            return ''
        span = (
            'no messages'
            if self.first_log_ns is None
            else f'log time {self.first_log_ns * 1e-9:.9g} s to {self.last_log_ns * 1e-9:.9g} s '
            f'({(self.last_log_ns - self.first_log_ns) * 1e-9:.6g} s)'
        )
        parts = [
            f'{self.message_count} messages recovered ({span})',
            f'{self.bytes_dropped} of {self.file_size} bytes dropped',
        ]
        if self.truncated:
            parts.append(
                'no summary/footer (writer killed hard or file cut short)'
                + (f': {self.stop_reason}' if self.stop_reason else '')
            )
        if self.corrupt_chunks:
            parts.append(f'{self.corrupt_chunks} corrupt chunk(s) skipped')
        if self.undecodable:
            parts.append(
                'undecodable messages skipped: '
                + ', '.join(f'{t} {n}' for t, n in sorted(self.undecodable.items()))
            )
        if self.orphan_messages:
            parts.append(f'{self.orphan_messages} messages without their channel record skipped')
        return '; '.join(parts)


def open_checked(path: str | Path) -> tuple[Path, Any]:
    p = Path(path)
    if not p.exists():
        raise BagReadError(f'{str(p)!r}: no such file; expected an MCAP recording (.mcap)')
    if p.is_dir():
        raise BagReadError(f'{str(p)!r} is a directory; expected an MCAP recording file (.mcap)')
    if not p.is_file():
        raise BagReadError(
            f'{str(p)!r} is not a regular file; expected an MCAP recording file (.mcap)'
        )
    try:
        fh = open(p, 'rb')
    except OSError as exc:
        raise BagReadError(
            f'{str(p)!r}: cannot be opened ({exc.strerror}); expected a readable MCAP recording'
        ) from None
    magic = fh.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        fh.close()
        if not magic:
            what = 'an empty file'
        elif magic.startswith(MCAP_MAGIC_PREFIX) and len(magic) == len(MCAP_MAGIC):
            what = (
                f'an MCAP file of major version {magic[5:6].decode("latin-1")!r}, newer than this '
                'reader '
                f"understands (version '0'); update pulsejet/mcap to read it"
            )
        elif len(magic) < len(MCAP_MAGIC) and MCAP_MAGIC.startswith(magic):
            what = f'cut short ({len(magic)} bytes, not even the MCAP magic)'
        else:
            what = 'not an MCAP file (bad magic bytes)'
        raise BagReadError(f'{str(p)!r} is {what}; expected an MCAP recording (.mcap)')
    return p, fh


def format_version(library: str) -> int | None:
    """
    Return the pulsejet format version recorded in an MCAP header's library field.

    None when the file is not pulsejet's.
    """
    match = _FORMAT_RE.search(library or '')
    return int(match.group(1)) if match else None


def check_header(header: Header, info: BagInfo, path: Path, *, repairing: bool = False) -> None:
    """
    Note the header's profile and library in `info`; refuse a file pulsejet must not read.

    Raises BagReadError for a profile other than ros2 or a pulsejet format newer than
    FORMAT_VERSION (worded for bag.repair when `repairing`).
    """
    info.profile = header.profile
    info.library = header.library
    if header.profile != 'ros2':
        raise BagReadError(
            f'{str(path)!r} is an MCAP file with profile {header.profile!r}; '
            'expected a ROS 2 recording (profile "ros2")'
        )
    version = format_version(header.library)
    if version is not None and version > FORMAT_VERSION:
        if repairing:
            what = f'repairs (format {FORMAT_VERSION}); update pulsejet'
        else:
            what = (
                f'reads (format {FORMAT_VERSION}); allowed: recordings of format <= '
                f'{FORMAT_VERSION}; update pulsejet to read it'
            )
        raise BagReadError(
            f'{str(path)!r} was written in pulsejet recording format {version}, newer than this '
            f'pulsejet {what}'
        )


#: the record kinds the reader needs, by opcode; indexes and statistics are rebuilt by whoever
#: needs them
_RECORDS = {
    Opcode.HEADER: Header,
    Opcode.SCHEMA: Schema,
    Opcode.CHANNEL: Channel,
    Opcode.CHUNK: Chunk,
    Opcode.METADATA: Metadata,
    Opcode.ATTACHMENT: Attachment,
    Opcode.DATA_END: DataEnd,
    Opcode.FOOTER: Footer,
}


def _parse(opcode: int, body: bytes) -> Any:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(body))
    record = _RECORDS.get(opcode)
    return record.read(stream) if record is not None else None


def _chunk_records(chunk: Chunk) -> list[Any]:
    if chunk.compression not in ('', 'zstd', 'lz4'):
        raise ValueError(f'unsupported chunk compression {chunk.compression!r}')
    if chunk.uncompressed_size > MAX_CHUNK_UNCOMPRESSED:
        raise ValueError(f'chunk claims {chunk.uncompressed_size} uncompressed bytes')
    if chunk.compression == '' and chunk.uncompressed_size != len(chunk.data):
        raise ValueError('uncompressed chunk size mismatch')
    records = breakup_chunk(chunk, validate_crc=True)
    return records


# Whatever a parser or decompressor raises on damaged bytes (zstd, lz4, struct, utf-8, mcap's own
# EndOfFile ...): the record is corrupt. Only BaseExceptions (KeyboardInterrupt) pass.
_CORRUPT = (Exception,)


_CHUNK_FIXED = struct.Struct(
    '<QQQII'
)  # message start/end time, uncompressed size, crc, compression length
MAX_RESYNC_CANDIDATES = 100_000  # chunk-looking offsets tried after a broken frame


def _chunk_at(buf: Any, i: int, size: int) -> bool:
    """
    Tell whether there is an intact chunk record at offset i.

    Intact: the frame fits and the CRC of its content is valid.
    """
    if i + 9 + _CHUNK_FIXED.size > size or buf[i] != Opcode.CHUNK:
        return False
    length = int.from_bytes(buf[i + 1: i + 9], 'little')
    if length > size - i - 9 or length < _CHUNK_FIXED.size + 8:
        return False
    _, _, usize, crc, clen = _CHUNK_FIXED.unpack_from(buf, i + 9)
    if clen > 4 or crc == 0 or usize > MAX_CHUNK_UNCOMPRESSED:
        return False
    off = i + 9 + _CHUNK_FIXED.size
    if bytes(buf[off: off + clen]) not in (b'', b'zstd', b'lz4'):
        return False
    dlen = int.from_bytes(buf[off + clen: off + clen + 8], 'little')
    if _CHUNK_FIXED.size + clen + 8 + dlen != length:
        return False
    try:
        _chunk_records(_parse(Opcode.CHUNK, bytes(buf[i + 9: i + 9 + length])))
    except _CORRUPT:
        return False
    return True


def _resync(fh: Any, start: int, size: int) -> int | None:
    """
    Return the offset of the next intact chunk at or after `start`, or None.

    Used after a damaged record frame.
    """
    import mmap

    try:
        buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
        return None
    try:
        i, tried = start, 0
        while tried < MAX_RESYNC_CANDIDATES:
            i = buf.find(bytes([Opcode.CHUNK]), i, size)
            if i < 0:
                return None
            tried += 1
            if _chunk_at(buf, i, size):
                return i
            i += 1
        return None
    finally:
        buf.close()


def _summary_definitions(fh: Any, size: int) -> list[Any]:
    """
    Return the Schema and Channel records of the summary section.

    Only when the footer and the summary CRC are intact: they name the channels of messages whose
    own channel record sat in a damaged chunk.
    """
    footer_len = 9 + 20
    footer_pos = size - len(MCAP_MAGIC) - footer_len
    if footer_pos <= len(MCAP_MAGIC):
        return []
    fh.seek(footer_pos)
    tail = fh.read(footer_len + len(MCAP_MAGIC))
    if (
        len(tail) != footer_len + len(MCAP_MAGIC)
        or tail[-len(MCAP_MAGIC):] != MCAP_MAGIC
        or tail[0] != Opcode.FOOTER
        or int.from_bytes(tail[1:9], 'little') != 20
    ):
        return []
    summary_start, _, crc = struct.unpack_from('<QQI', tail, 9)
    if crc == 0 or not len(MCAP_MAGIC) < summary_start <= footer_pos:
        return []
    fh.seek(summary_start)
    data = fh.read(footer_pos - summary_start)
    if zlib.crc32(tail[:25], zlib.crc32(data)) != crc:
        return []
    out, i = [], 0
    while i + 9 <= len(data):
        opcode, length = struct.unpack_from('<BQ', data, i)
        if length > len(data) - i - 9:
            break
        try:
            if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                out.append((None, _parse(opcode, data[i + 9: i + 9 + length])))
            elif opcode == Opcode.METADATA_INDEX:
                # the metadata record it points to (e.g. the run's scene) even if its frame is
                # damaged
                index = MetadataIndex.read(
                    ReadDataStream(io.BytesIO(data[i + 9: i + 9 + length]))
                )
                if (
                    len(MCAP_MAGIC) <= index.offset
                    and index.offset + index.length <= summary_start
                    and 9 <= index.length <= MAX_CHUNK_UNCOMPRESSED
                ):
                    fh.seek(index.offset)
                    raw = fh.read(index.length)
                    if raw[0] == Opcode.METADATA:
                        out.append((index.offset, _parse(Opcode.METADATA, raw[9:])))
        except _CORRUPT:
            pass
        i += 9 + length
    return out


def iter_records(fh: Any, info: BagInfo) -> Iterator[Any]:
    """
    Yield the records in file order, chunks opened.

    A record whose frame is intact but whose content is corrupt (a chunk failing its CRC or its
    decompression) is skipped. After a broken frame (an invalid opcode or a length running past the
    end of the file) reading resumes at the next intact chunk (found by its CRC), so damage in the
    middle costs the damaged part only; a cut-off tail ends the read. Every byte not read is
    counted in info.bytes_dropped; info.truncated is set without a footer and its closing magic.
    """
    try:
        size = os.fstat(fh.fileno()).st_size
    except (OSError, AttributeError, io.UnsupportedOperation):
        size = 0
    info.file_size = size
    try:
        summary = _summary_definitions(fh, size)
    except _CORRUPT:
        summary = []
    preload = [record for _, record in summary]
    preloaded_metadata = {offset for offset, _ in summary if offset is not None}
    pos = len(MCAP_MAGIC)
    fh.seek(pos)
    info.valid_bytes = pos
    skipped = 0
    footer_seen = False
    first = True
    seen_chunk = data_end = False
    try:
        while True:
            head = fh.read(9)
            if not head:
                info.stop_reason = info.stop_reason or f'file ends at byte {pos} without a footer'
                break
            broken = None
            opcode, length = struct.unpack('<BQ', head) if len(head) == 9 else (0, 0)
            if len(head) < 9:
                broken = f'record header at byte {pos} cut short'
            elif opcode not in _KNOWN_OPCODES and opcode < 0x80:
                broken = f'invalid record opcode 0x{opcode:02x} at byte {pos}'
            elif length > size - pos - 9:
                broken = f'record at byte {pos} ({length} bytes) runs past the end of the file'
            if broken is None and first and opcode != Opcode.HEADER:
                broken = f'the header record at byte {pos} is damaged (opcode 0x{opcode:02x})'
            if broken is not None:
                if first:  # a damaged header: profile and library unknown, the data may be intact
                    first = False
                    yield from preload
                    preload = []
                found = _resync(fh, pos + 1, size)
                if found is None:
                    info.stop_reason = broken
                    break
                info.stop_reason = f'{broken}; resumed at the next intact chunk (byte {found})'
                skipped += found - pos
                pos = found
                info.valid_bytes = pos
                fh.seek(pos)
                continue
            first = False
            body = fh.read(length)
            end = pos + 9 + length
            try:
                record = _parse(opcode, body)
                inner = _chunk_records(record) if opcode == Opcode.CHUNK else None
            except _CORRUPT:
                if opcode == Opcode.FOOTER:
                    info.stop_reason = f'corrupt footer record at byte {pos}'
                    break
                if opcode == Opcode.HEADER:  # profile and library unknown: read the data anyway
                    yield from preload
                    preload = []
                # the frame is intact (its length fits the file): skip this record only
                if opcode == Opcode.CHUNK:
                    info.corrupt_chunks += 1
                skipped += 9 + length
                pos = end
                info.valid_bytes = pos
                continue
            pos = end
            info.valid_bytes = pos
            if inner is not None:
                seen_chunk = True
                yield from inner
            elif isinstance(record, DataEnd):
                data_end = True
            elif isinstance(record, Metadata) and pos - 9 - length in preloaded_metadata:
                continue  # already read through the summary's metadata index
            elif isinstance(record, Message) and (seen_chunk or data_end):
                # a chunked file has no message outside its chunks: a damaged index record, not
                # data
                skipped += 9 + length
                continue
            elif record is not None:
                yield record
                if preload and isinstance(record, Header):
                    yield from preload  # the summary's channels, before any message needs them
                    preload = []
                if isinstance(record, Footer):
                    # complete only with the closing magic (other readers check it)
                    if fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC:
                        footer_seen = True
                        info.valid_bytes = pos + len(MCAP_MAGIC)
                    else:
                        info.stop_reason = (
                            'the closing magic after the footer is missing or damaged'
                        )
                    break
    finally:
        info.truncated = not footer_seen
        info.bytes_dropped = skipped + max(size - info.valid_bytes, 0)
