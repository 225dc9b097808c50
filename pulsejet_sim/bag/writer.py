"""
MCAP writer laid out the way rosbag2 (rosbag2_storage_mcap, Jazzy) writes it.

Layout: profile `ros2`; one schema per message type with encoding `ros2msg` and the complete
definition text (msgdefs.full_text); one channel per topic with encoding `cdr` and metadata
`offered_qos_profiles` / `topic_type_hash`; zstd- or lz4-compressed chunks with message indexes;
summary (schemas, channels, statistics, chunk indexes) and a `rosbag2` metadata record on close.

Crash safety:
- close() is idempotent and also runs at interpreter exit;
- install_signal_handlers(writer) closes the file on SIGINT/SIGTERM before the process exits;
- chunks are bounded in size and age: a message is in a closed chunk handed to the OS at most
  flush_period_s after it was written (checked on every write and by a background thread while
  the writer is idle), so a hard kill (SIGKILL; power loss aside) loses at most the messages of
  the last flush_period_s; bag.reader reads such a truncated file up to its last complete chunk
  and `pulsejet repair` (bag.repair) rewrites it into a complete one with all its metadata.

Format: the MCAP header's library field carries `pulsejet-format=<FORMAT_VERSION>`; a reader
refuses a recording of a newer format with a clear message (bag.reader.FORMAT_VERSION).

Topic names are stored fully qualified like rosbag2 ('pulsejet/velocity' -> '/pulsejet/velocity').

Three ways in: write() per message (the ROS recorder, with rclpy's bytes; ros.bag_messages for
rclpy message objects); write_records() for the messages of one publication as bag.cdr bytes
(resim, no rclpy), which writes the same file faster; write_chunk() for a stretch of Message
records laid out by the caller (the offline runner: bag.publications), one MCAP chunk each.
"""

from __future__ import annotations

import atexit
import datetime
import io
import json
import math
import os
from pathlib import Path
import signal
import struct
import threading
import time
from types import FrameType
from typing import Any, Callable, Iterable, Sequence, TYPE_CHECKING
import weakref
import zlib

from mcap.records import ChunkIndex, MessageIndex
from mcap.writer import CompressionType, Writer
import numpy as np
from pulsejet_sim.bag import msgdefs
from pulsejet_sim.bag.records import FORMAT_VERSION
from pulsejet_sim.core.schema import load_own_yaml
import yaml

if TYPE_CHECKING:
    from pulsejet_sim.bag.publications import Stretch

LIBRARY = f'pulsejet_sim.bag pulsejet-format={FORMAT_VERSION} (rosbag2_storage_mcap layout)'
COMPRESSIONS = {
    'zstd': CompressionType.ZSTD,
    'lz4': CompressionType.LZ4,
    'none': CompressionType.NONE,
}


class BagError(RuntimeError):
    """Bag writer misuse (unknown topic, write after close, ...); the message names the value."""


def qualify_topic(topic: str) -> str:
    """
    Return the fully qualified topic name as rosbag2 records it.

    'pulsejet/velocity' -> '/pulsejet/velocity'.
    """
    if not isinstance(topic, str) or not topic.strip('/') or ' ' in topic:
        raise BagError(
            f'topic name {topic!r} is not a ROS topic name; expected e.g. "pulsejet/velocity"'
        )
    return topic if topic.startswith('/') else '/' + topic


def _topic_type(topic: str) -> str:
    from pulsejet_sim.core.topics import TOPIC_TYPES

    try:
        return TOPIC_TYPES[topic]
    except KeyError:
        raise BagError(
            f'topic {topic!r} is not a pulsejet topic; allowed: {sorted(TOPIC_TYPES)} (or '
            'add_topic it first)'
        ) from None


class BagWriter:
    """
    Write CDR-serialized ROS 2 messages to one MCAP file readable by rosbag2, rosbags and Foxglove.

    Usage::

        with BagWriter('run.mcap') as bag:
            bag.add_topic('pulsejet/velocity', 'geometry_msgs/msg/TwistStamped')
            bag.write('pulsejet/velocity', serialize_message(msg), log_time_ns)

    Thread-safe: writes from several executor threads and a close() from another thread are
    serialized. close() syncs the file to the disk (os.fsync) unless sync_on_close=False: every
    write is with the OS by then either way, so only a power loss or an OS crash tells them apart.
    zstd_level: the level of write_chunk's zstd chunks (default 1, rosbag2's: mcap's C++ writer,
    CompressionLevel::Default; -3 is its Fast); messages written one by one go through mcap's
    writer (level 3).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        compression: str = 'zstd',
        chunk_size_bytes: int = 256 * 1024,
        flush_period_s: float = 1.0,
        sync_on_close: bool = True,
        zstd_level: int = 1,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(
                f'compression={compression!r} not supported; allowed: {sorted(COMPRESSIONS)}'
            )
        if not (isinstance(chunk_size_bytes, int) and chunk_size_bytes > 0):
            raise BagError(
                f'chunk_size_bytes={chunk_size_bytes!r} rejected; allowed: a positive integer'
            )
        if not (
            isinstance(flush_period_s, (int, float))
            and flush_period_s > 0
            and math.isfinite(flush_period_s)
        ):
            raise BagError(
                f'flush_period_s={flush_period_s!r} rejected; allowed: a positive finite number '
                'of s'
            )
        self.path = Path(path)
        self.compression = compression
        self.chunk_size_bytes = chunk_size_bytes
        self.sync_on_close = bool(sync_on_close)
        if not (isinstance(zstd_level, int) and not isinstance(zstd_level, bool)
                and -100 <= zstd_level <= 22):
            raise BagError(
                f'zstd_level={zstd_level!r} rejected; allowed: an integer in [-100, 22]'
            )
        self.zstd_level = zstd_level
        self.flush_period_s = float(flush_period_s)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, 'wb')
        self._writer = Writer(
            self._file, chunk_size=chunk_size_bytes, compression=COMPRESSIONS[compression]
        )
        self._writer.start(profile='ros2', library=LIBRARY)
        self._file.flush()
        self._lock = threading.RLock()
        self._schemas: dict[str, int] = {}  # type name -> schema id
        self._channels: dict[str, int] = {}  # qualified topic -> channel id
        self._route: dict[str, tuple[int, str]] = {}  # write_records: topic -> (channel, name)
        self._topic_info: dict[str, dict[str, Any]] = {}
        self._counts: dict[str, int] = {}
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self._last_flush = time.monotonic()
        self._pending_since: float | None = None  # monotonic time of the oldest unflushed message
        self._fast = _FastChunk.attach(self._writer, chunk_size_bytes)
        self._pending_chunk = None  # write_chunk's chunk being compressed, written next call
        self._closed = False
        self._busy_thread: int | None = None  # thread id inside write(), for signal deferral
        self._pending_signal: int | None = None
        self._previous_handlers: dict = {}  # signal -> handler before install_signal_handlers
        self._close_hooks: list[Callable[[], None]] = []
        # Close at interpreter exit too (sys.exit, an uncaught exception), without keeping self
        # alive.
        self._atexit = _weak_close(self)
        atexit.register(self._atexit)
        # An idle writer (no write() to trigger the flush) still flushes within flush_period_s:
        # a thread started with the first message left in an open chunk (write_chunk leaves
        # none, so a writer fed only chunks starts none)
        self._stop_flusher = threading.Event()
        self._flusher: threading.Thread | None = None

    def _start_flusher(self) -> None:
        self._flusher = threading.Thread(
            target=_flush_loop,
            args=(weakref.ref(self), self._stop_flusher, self._tick_s()),
            name=f'bag-flush:{self.path.name}',
            daemon=True,
        )
        self._flusher.start()

    def _tick_s(self) -> float:
        return min(max(self.flush_period_s / 10.0, 0.005), 0.5)

    def _flush_due(self, now: float) -> bool:
        return (
            self._pending_since is not None
            and now - self._pending_since >= self.flush_period_s - self._tick_s()
        )

    # -- context manager ------------------------------------------------------------------------
    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- properties -----------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def message_counts(self) -> dict[str, int]:
        """Messages written per qualified topic name."""
        with self._lock:
            return dict(self._counts)

    @property
    def message_count(self) -> int:
        """Messages written on every topic together."""
        with self._lock:
            return sum(self._counts.values())

    @property
    def topics(self) -> dict[str, str]:
        """Qualified topic name -> type name of every added topic."""
        with self._lock:
            return {t: info['type'] for t, info in self._topic_info.items()}

    # -- writing --------------------------------------------------------------------------------
    def add_topic(
        self,
        topic: str,
        type_name: str,
        offered_qos_profiles: str = '',
        definition: str | None = None,
        channel_metadata: dict[str, str] | None = None,
    ) -> str:
        """
        Register a topic (idempotent for the same type); returns the qualified name.

        offered_qos_profiles: the YAML rosbag2 stores (see qos_profiles_yaml); '' when unknown.
        definition: complete ros2msg text to store instead of the installed one (used by repair()).
        channel_metadata: the channel's metadata to store verbatim (repair: every key of the
        damaged file's channel, `offered_qos_profiles` and `topic_type_hash` included) instead of
        the computed one. Raises BagError for a topic re-added with another type,
        MessageDefinitionError when the type's .msg files are not installed.
        """
        name = qualify_topic(topic)
        msgdefs.split_type_name(type_name)
        with self._mutating():
            if name in self._channels:
                if self._topic_info[name]['type'] != type_name:
                    raise BagError(
                        f'topic {name!r} already added with type '
                        f'{self._topic_info[name]["type"]!r}, not {type_name!r}'
                    )
                return name
            schema_id = self._schemas.get(type_name)
            if schema_id is None:
                text = definition if definition is not None else msgdefs.full_text(type_name)
                schema_id = self._writer.register_schema(
                    type_name, 'ros2msg', text.encode('utf-8')
                )
                self._schemas[type_name] = schema_id
            if channel_metadata is not None:
                metadata = {str(k): str(v) for k, v in channel_metadata.items()}
                offered_qos_profiles = metadata.get('offered_qos_profiles', '')
                type_hash = metadata.get('topic_type_hash', '')
            else:
                type_hash = msgdefs.type_hash(type_name)
                metadata = {
                    'offered_qos_profiles': offered_qos_profiles,
                    'topic_type_hash': type_hash,
                }
            self._channels[name] = self._writer.register_channel(name, 'cdr', schema_id, metadata)
            self._topic_info[name] = {
                'type': type_name,
                'qos': offered_qos_profiles,
                'hash': type_hash,
            }
            self._counts[name] = 0
            return name

    def write(
        self, topic: str, cdr: bytes, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """
        Append one CDR-serialized message.

        log_time_ns is the receive (or simulation) time in ns.
        """
        name = topic if topic in self._channels else qualify_topic(topic)
        if not isinstance(log_time_ns, int) or log_time_ns < 0:
            raise BagError(f'log_time_ns={log_time_ns!r} rejected; allowed: an integer >= 0 (ns)')
        with self._mutating():
            channel = self._channels.get(name)
            if channel is None:
                raise BagError(
                    f'topic {name!r} not added; call add_topic first (added: '
                    f'{sorted(self._channels)})'
                )
            self._counts[name] += 1
            self._writer.add_message(
                channel,
                log_time_ns,
                bytes(cdr),
                log_time_ns if publish_time_ns is None else int(publish_time_ns),
                sequence=self._counts[name],
            )
            self._first_ns = (
                log_time_ns if self._first_ns is None else min(self._first_ns, log_time_ns)
            )
            self._last_ns = (
                log_time_ns if self._last_ns is None else max(self._last_ns, log_time_ns)
            )
            now = time.monotonic()
            if self._pending_since is None:
                self._pending_since = now
                if self._flusher is None:
                    self._start_flusher()
            if self._flush_due(now):
                self._flush_locked()

    def write_records(self, records: Iterable[tuple[str, bytes]], log_time_ns: int) -> None:
        """
        Append several CDR-serialized messages of pulsejet topics, all stamped log_time_ns.

        records: (topic, CDR bytes), e.g. from bag.cdr.TopicEncoder; a topic not yet added is
        added with its interface.TOPIC_TYPES type. The file is byte for byte the one write() per
        message gives; this path takes the lock once per batch and, with the pinned mcap library,
        appends the batch's Message records to the open chunk at once (_FastChunk), which lets an
        offline run record at nearly the speed of its physics.
        """
        if not isinstance(log_time_ns, int) or log_time_ns < 0:
            raise BagError(f'log_time_ns={log_time_ns!r} rejected; allowed: an integer >= 0 (ns)')
        with self._mutating():
            if self._fast is not None:
                self._fast.add(records, log_time_ns, self._route, self._counts, self._route_of)
            else:
                for topic, cdr in records:
                    channel, name = self._route.get(topic) or self._route_of(topic)
                    self._counts[name] += 1
                    self._writer.add_message(
                        channel, log_time_ns, cdr, log_time_ns, self._counts[name]
                    )
            self._first_ns = (
                log_time_ns if self._first_ns is None else min(self._first_ns, log_time_ns)
            )
            self._last_ns = (
                log_time_ns if self._last_ns is None else max(self._last_ns, log_time_ns)
            )
            now = time.monotonic()
            if self._pending_since is None:
                self._pending_since = now
                if self._flusher is None:
                    self._start_flusher()
            if self._flush_due(now):
                self._flush_locked()

    def channel_ids(self, topics: Sequence[str]) -> dict[str, int]:
        """
        Add the pulsejet topics (interface.TOPIC_TYPES types) in this order; return their channels.

        For a producer that lays out its own records (write_chunk): topic -> channel id.
        """
        return {topic: self._route_of(topic)[0] for topic in topics}

    def write_chunk(self, stretch: 'Stretch') -> None:
        """
        Write a stretch of Message records (bag.publications.Stretch) as one MCAP chunk.

        The records must be on channels added here (channel_ids), with sequences continuing each
        channel's count and log times not before what was written. The chunk is compressed as
        the writer's other chunks, followed by its message indexes and counted in the summary
        (statistics, chunk index), as mcap's writer does for the same records; schema and
        channel records added since the last chunk open it. The compression (zstd and zlib's
        CRC release the GIL) runs in a worker thread while the caller goes on; the chunk goes to
        the file at the next call into the writer (the next write_chunk, a flush, close), so a
        producer handing over a chunk every flush_period_s / 2 keeps the flush guarantee. With
        an mcap library that does not look as expected, the records go through mcap's
        add_message one by one (the same messages in different chunks).
        """
        if not stretch.size:
            return
        counts = {channel: len(table) for channel, table in stretch.index}
        names = {route[0]: route[1] for route in self._route.values()}
        unknown = sorted(set(counts) - set(names))
        if unknown:
            raise BagError(
                f'channel ids {unknown} were not added with channel_ids; allowed: {sorted(names)}'
            )
        if stretch.first_ns < 0:
            raise BagError(
                f'log_time_ns={stretch.first_ns!r} rejected; allowed: an integer >= 0 (ns)'
            )
        with self._mutating():  # writes the chunk handed over before, if any
            if self._fast is not None:
                # compressed by a worker thread while the caller runs on; written by the next
                # call into the writer (or close), in order
                self._pending_chunk = self._fast.write_chunk(
                    stretch, self.compression, self.zstd_level
                )
            else:
                data = b''.join(stretch.records)
                offset = 0
                while offset < len(data):
                    _, length, channel, sequence, log_ns, publish_ns = _MESSAGE_HEAD.unpack_from(
                        data, offset
                    )
                    body = data[offset + _MESSAGE_HEAD.size:offset + 9 + length]
                    self._writer.add_message(channel, log_ns, body, publish_ns, sequence)
                    offset += 9 + length
            for channel, count in counts.items():
                self._counts[names[channel]] += count
            first, last = stretch.first_ns, stretch.last_ns
            self._first_ns = first if self._first_ns is None else min(self._first_ns, first)
            self._last_ns = last if self._last_ns is None else max(self._last_ns, last)
            if self._fast is None:
                self._flush_locked()  # the chunk is closed: hand it to the OS now

    def _write_pending_chunk(self) -> None:
        """Write the chunk write_chunk handed over (waiting for its compression); lock held."""
        pending, self._pending_chunk = self._pending_chunk, None
        if pending is not None:
            self._fast.finish_chunk_record(pending)
            self._writer.flush()  # to the OS

    def _route_of(self, topic: str) -> tuple[int, str]:
        """(channel id, qualified name) of a topic as write_records gets it; adds the topic."""
        name = qualify_topic(topic)
        if name not in self._channels:
            self.add_topic(name, _topic_type(topic))
        route = self._route[topic] = (self._channels[name], name)
        return route

    def _mutating(self) -> '_Mutating':
        """
        Hold the lock and mark this thread busy (a context manager; nests).

        So a signal handler landing mid-record defers the close to the end of the operation instead
        of cutting the record in half.
        """
        return _Mutating(self)

    def add_attachment(
        self,
        name: str,
        data: bytes,
        media_type: str = 'application/octet-stream',
        log_time_ns: int = 0,
        create_time_ns: int = 0,
    ) -> None:
        """Write an MCAP attachment record (repair copies a damaged file's attachments)."""
        with self._mutating():
            self._writer.add_attachment(
                create_time=int(create_time_ns),
                log_time=int(log_time_ns),
                name=str(name),
                media_type=str(media_type),
                data=bytes(data),
            )

    def add_metadata(self, name: str, metadata: dict[str, str]) -> None:
        """Write an MCAP metadata record (string keys and values), e.g. the scene a run used."""
        self._check_open()
        with self._mutating():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in metadata.items()})

    def flush(self) -> None:
        """
        Close the open chunk and push everything to the OS.

        A later hard kill cannot lose it.
        """
        if not self._closed:
            with self._mutating():
                self._flush_locked()

    def flush_if_due(self) -> None:
        """
        Call flush() if the oldest unflushed message is about flush_period_s old.

        The writer's own background thread calls this too; a timer calling it is harmless.
        """
        if not self._closed and self._flush_due(time.monotonic()):
            with self._mutating():
                if self._flush_due(time.monotonic()):
                    self._flush_locked()

    def _flush_locked(self) -> None:
        self._write_pending_chunk()
        self._writer.flush()
        self._last_flush = time.monotonic()
        self._pending_since = None

    def on_close(self, hook: Callable[[], None]) -> None:
        """
        Run hook() first in close(), the file still open.

        A producer that buffers messages (the offline runner) hands them over there, so a close
        from a signal handler or at interpreter exit loses none of them.
        """
        self._close_hooks.append(hook)

    def close(self) -> None:
        """Write the summary and the rosbag2 metadata record and close the file. Idempotent."""
        pending = None
        with self._lock:
            if self._closed:
                return
            self._busy_thread = (
                threading.get_ident()
            )  # a signal landing now is deferred, not re-entrant
            try:
                hooks, self._close_hooks = self._close_hooks, []
                for hook in hooks:
                    hook()
                self._write_pending_chunk()
                self._writer.add_metadata(
                    'rosbag2', {'serialized_metadata': self._rosbag2_metadata()}
                )
                self._writer.finish()
                self._file.flush()
                if self.sync_on_close:  # on the disk, not only with the OS (a power loss)
                    os.fsync(self._file.fileno())
            finally:
                self._closed = True
                self._stop_flusher.set()
                self._file.close()
                atexit.unregister(self._atexit)
                self._busy_thread = None
                pending, self._pending_signal = self._pending_signal, None
        if pending is not None:
            _redeliver(pending, self._previous_handlers.get(pending))

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f'bag {str(self.path)!r} is closed')

    def _rosbag2_metadata(self) -> str:
        """
        Return the `rosbag2_bagfile_information` YAML that rosbag2 stores in the file.

        Metadata version 9, written in YAML's JSON subset (flow style, which rosbag2's yaml-cpp
        and PyYAML read as they read block style): json is about 20x faster than PyYAML's
        representer, a fixed cost of every recording.
        """
        start = self._first_ns or 0
        duration = (self._last_ns - start) if self._last_ns is not None else 0
        total = sum(self._counts.values())
        topics = []
        for name, info in self._topic_info.items():
            try:
                qos = load_own_yaml(info['qos']) if info['qos'] else []
            except yaml.YAMLError:  # text copied from a damaged file by repair: keep it as text
                qos = info['qos']
            topics.append(
                {
                    'topic_metadata': {
                        'name': name,
                        'type': info['type'],
                        'serialization_format': 'cdr',
                        'offered_qos_profiles': qos,
                        'type_description_hash': info['hash'],
                    },
                    'message_count': self._counts[name],
                }
            )
        data = {
            'rosbag2_bagfile_information': {
                'version': 9,
                'storage_identifier': 'mcap',
                'duration': {'nanoseconds': duration},
                'starting_time': {'nanoseconds_since_epoch': start},
                'message_count': total,
                'topics_with_message_count': topics,
                'compression_format': '',
                'compression_mode': '',
                'relative_file_paths': [self.path.name],
                'files': [
                    {
                        'path': self.path.name,
                        'starting_time': {'nanoseconds_since_epoch': start},
                        'duration': {'nanoseconds': duration},
                        'message_count': total,
                    }
                ],
                'custom_data': {
                    'writer': LIBRARY,
                    'closed_at': datetime.datetime.now(datetime.timezone.utc).isoformat(),
                },
                'ros_distro': os.environ.get('ROS_DISTRO', 'jazzy'),
            }
        }
        return json.dumps(data)


class _Mutating:
    """
    BagWriter._mutating: the lock held, this thread marked busy, a deferred signal acted on last.

    A class rather than a contextlib generator: the offline runner enters it twice per
    publication, and the generator costs about as much as writing the messages.
    """

    __slots__ = ('bag', 'outer')

    def __init__(self, bag: BagWriter) -> None:
        self.bag = bag

    def __enter__(self) -> None:
        bag = self.bag
        bag._lock.acquire()
        try:
            bag._check_open()
        except BaseException:
            bag._lock.release()
            raise
        self.outer = bag._busy_thread is not None
        bag._busy_thread = threading.get_ident()
        if bag._pending_chunk is not None:  # whatever comes next goes after it in the file
            try:
                bag._write_pending_chunk()
            except BaseException:
                self.__exit__()
                raise

    def __exit__(self, *exc: object) -> None:
        bag = self.bag
        pending = None
        try:
            if not self.outer:
                bag._busy_thread = None
                pending, bag._pending_signal = bag._pending_signal, None
        finally:
            bag._lock.release()
        if pending is not None:
            bag.close()
            _redeliver(pending, bag._previous_handlers.get(pending))


_MESSAGE_HEAD = struct.Struct('<BQHIQQ')  # MCAP Message record: opcode, length, fields


class _FastChunk:
    """
    Appends MCAP Message records to mcap.Writer's open chunk without a Message object each.

    Writes exactly what mcap.writer.Writer.add_message writes (record, message index entry,
    statistics, chunk finalised at the same size), through the writer's private chunk builder,
    statistics and finalize method of the pinned mcap (requirements.txt). attach() returns None
    when that library does not look the way this expects; write_records then takes the public
    add_message path (test_bag checks the two give identical files and that the pinned library
    takes the fast one).
    """

    __slots__ = ('writer', 'builder', 'stats', 'finalize', 'chunk_size', 'finish_chunk', 'flush',
                 'stream', 'chunk_indexes', 'compressor')

    @classmethod
    def attach(cls, writer: Writer, chunk_size: int) -> '_FastChunk | None':
        from mcap._chunk_builder import ChunkBuilder
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import Statistics
        from mcap.writer import IndexType

        fast = cls()
        fast.writer = writer
        fast.builder = getattr(writer, '_Writer__chunk_builder', None)
        fast.stats = getattr(writer, '_Writer__statistics', None)
        fast.finalize = getattr(writer, '_Writer__maybe_finalize_chunk', None)
        fast.chunk_size = chunk_size
        fast.finish_chunk = getattr(writer, '_Writer__finalize_chunk', None)
        fast.flush = getattr(writer, '_Writer__flush', None)
        fast.stream = getattr(writer, '_Writer__stream', None)
        fast.chunk_indexes = getattr(writer, '_Writer__chunk_indices', None)
        fast.compressor = None
        expected = (
            type(fast.builder) is ChunkBuilder
            and type(getattr(fast.builder, 'record_writer', None)) is RecordBuilder
            and isinstance(getattr(fast.builder.record_writer, '_buffer', None), io.BytesIO)
            and isinstance(fast.stats, Statistics)
            and callable(fast.finalize)
            and callable(fast.finish_chunk)
            and callable(fast.flush)
            and hasattr(fast.stream, 'tell')
            and isinstance(fast.chunk_indexes, list)
            and getattr(writer, '_Writer__enable_crcs', None) is True
            and getattr(writer, '_Writer__index_types', None) == IndexType.ALL
            and getattr(writer, '_Writer__chunk_size', None) == chunk_size
            and int(Opcode.MESSAGE) == 5
            and int(Opcode.MESSAGE_INDEX) == 7
        )
        return fast if expected else None

    def add(
        self,
        records: Sequence[tuple[str, bytes]],
        log_time_ns: int,
        route: dict[str, tuple[int, str]],
        counts: dict[str, int],
        route_of: Callable[[str], tuple[int, str]],
    ) -> None:
        """
        Append (topic, data) messages stamped log_time_ns (log = publish time).

        route maps a topic to (channel id, qualified name) (route_of adds a missing one);
        counts[name] is the channel's message count, the next message's sequence.
        """
        builder, stats, chunk_size = self.builder, self.stats, self.chunk_size
        # the statistics and chunk times add_message would leave after each message in turn
        _extend_statistics(stats, log_time_ns, log_time_ns, len(records))
        channel_counts = stats.channel_message_counts
        head = _MESSAGE_HEAD.pack
        i, n = 0, len(records)
        while i < n:
            if builder.num_messages == 0:
                builder.message_start_time = log_time_ns
            else:
                builder.message_start_time = min(builder.message_start_time, log_time_ns)
            builder.message_end_time = max(builder.message_end_time, log_time_ns)
            buffer = builder.record_writer._buffer  # a new one after each chunk closes
            indices = builder.message_indices
            offset = buffer.tell()
            parts = []
            while i < n:
                topic, data = records[i]
                known = route.get(topic)
                if known is None:  # adding the topic writes its records into this chunk first
                    break
                i += 1
                channel, name = known
                sequence = counts[name] = counts[name] + 1
                channel_counts[channel] += 1
                index = indices.get(channel)
                if index is None:
                    index = indices[channel] = _MessageIndex(channel_id=channel, records=[])
                index.records.append((log_time_ns, offset))
                parts.append(head(5, 22 + len(data), channel, sequence, log_time_ns, log_time_ns))
                parts.append(data)
                offset += 31 + len(data)
                if offset > chunk_size:  # add_message closes the chunk after this message
                    break
            builder.num_messages += len(parts) // 2
            buffer.write(b''.join(parts))
            if offset > chunk_size:
                self.finalize()
            elif i < n:
                route_of(records[i][0])

    def write_chunk(self, stretch: 'Stretch', compression: str, level: int) -> tuple:
        """
        Start the chunk of a stretch: its data handed to the compression worker.

        What mcap.writer.Writer's __finalize_chunk writes for a chunk holding these records
        (finish_chunk_record writes it): a message still open in mcap's chunk is written in a
        chunk of its own first; schema and channel records waiting there open this one.
        Returns what finish_chunk_record needs.
        """
        builder = self.builder
        if builder.num_messages:
            self.finish_chunk()
        prefix = builder.record_writer.end()  # schema and channel records added since
        builder.reset()
        pieces = [prefix, *stretch.records] if prefix else stretch.records
        size = len(prefix) + stretch.size
        if compression == 'zstd' and self.compressor is None:
            import zstandard

            self.compressor = zstandard.ZstdCompressor(level=level)
        # one piece (a laid-out stretch, no schema or channel record before it) is compressed as
        # it is; several are joined here: the worker holding the GIL for the copy could stall us
        data = memoryview(pieces[0]).cast('B') if len(pieces) == 1 else b''.join(pieces)
        job = _Job(lambda: _compress(data, compression, self.compressor))
        if _ChunkCompressor.in_thread:
            _ChunkCompressor.shared().submit(job)
        return job, stretch, len(prefix), size

    def finish_chunk_record(self, started: tuple) -> None:
        """Write a chunk write_chunk started: Chunk record, MessageIndex records, ChunkIndex."""
        job, stretch, shift, size = started
        crc, compression, packed = job.result()
        stats = self.stats
        tag = compression.encode()
        head = struct.pack(
            '<BQQQQII', 6, 8 + 8 + 8 + 4 + 4 + len(tag) + 8 + len(packed),
            stretch.first_ns, stretch.last_ns, size, crc, len(tag),
        ) + tag + struct.pack('<Q', len(packed))
        self.flush()  # whatever mcap holds outside a chunk goes first
        stream = self.stream
        chunk_start = stream.tell()
        stream.write(head)
        stream.write(packed)
        chunk_length = len(head) + len(packed)
        index_start = chunk_start + chunk_length
        # every channel's (log time, offset) entries in one array: one conversion, then a slice
        # of its bytes per channel
        entries = np.concatenate([table for _, table in stretch.index]).astype('<u8')
        if shift:
            entries[:, 1] += np.uint64(shift)
        data = entries.tobytes()
        offsets, parts, at, done = {}, [], index_start, 0
        for channel, table in stretch.index:
            length = 16 * len(table)
            parts.append(struct.pack('<BQHI', 7, 6 + length, channel, length))
            parts.append(data[done:done + length])
            done += length
            offsets[channel] = at
            at += 15 + length
        stream.write(b''.join(parts))
        self.chunk_indexes.append(ChunkIndex(
            message_start_time=stretch.first_ns,
            message_end_time=stretch.last_ns,
            chunk_start_offset=chunk_start,
            chunk_length=chunk_length,
            message_index_offsets=offsets,
            message_index_length=at - index_start,
            compression=compression,
            compressed_size=len(packed),
            uncompressed_size=size,
        ))
        count = sum(len(table) for _, table in stretch.index)
        _extend_statistics(stats, stretch.first_ns, stretch.last_ns, count)
        for channel, table in stretch.index:
            stats.channel_message_counts[channel] += len(table)
        stats.chunk_count += 1


def _compress(data: bytes, compression: str, compressor) -> tuple[int, str, bytes]:
    """
    Return (CRC-32, compression name, compressed bytes) of the data of an MCAP chunk.

    Two calls that release the GIL (zlib's CRC-32, the compression): in the worker, the GIL is
    held only for a few bytecodes around them, so a worker descheduled on a busy machine hardly
    ever holds up the producer.
    """
    crc = zlib.crc32(data)
    if compression == 'zstd':
        return crc, compression, compressor.compress(data)
    if compression == 'lz4':
        import lz4.frame

        return crc, compression, lz4.frame.compress(data)
    return crc, '', data


class _Job:
    """
    A call for _ChunkCompressor: run by whichever comes first, the worker or result().

    result() returns or raises the call's outcome; if the worker has not started the call yet
    (a busy machine can leave a woken thread waiting for a core), the caller runs it itself
    instead of waiting for the worker to be scheduled.
    """

    __slots__ = ('call', 'claim', 'done', 'value', 'error')

    def __init__(self, call: Callable[[], Any]) -> None:
        self.call, self.claim, self.done = call, threading.Lock(), threading.Event()
        self.value = self.error = None

    def run(self) -> None:
        if not self.claim.acquire(blocking=False):
            return  # taken by result()
        try:
            self.value = self.call()
        except BaseException as err:  # handed to the waiting caller
            self.error = err
        finally:
            self.done.set()

    def result(self) -> Any:
        self.run()
        self.done.wait()
        if self.error is not None:
            raise self.error
        return self.value


class _ChunkCompressor:
    """
    One daemon thread per process that compresses write_chunk's chunks, in order.

    zstd, lz4 and zlib's CRC-32 release the GIL, so a chunk compresses on another core while
    the producer (the offline runner's physics) goes on. Started with the first chunk, kept for
    the next writers (one thread start per process); a forked child starts its own.
    """

    _lock = threading.Lock()
    _shared: '_ChunkCompressor | None' = None
    in_thread = True  # False: each chunk compressed by the caller, when it is handed over

    @classmethod
    def shared(cls) -> '_ChunkCompressor':
        with cls._lock:
            if cls._shared is None or not cls._shared.thread.is_alive():
                cls._shared = cls()
            return cls._shared

    def __init__(self) -> None:
        from queue import SimpleQueue

        self.jobs: SimpleQueue = SimpleQueue()
        self.thread = threading.Thread(target=self._run, name='bag-compress', daemon=True)
        self.thread.start()

    def submit(self, job: _Job) -> None:
        self.jobs.put(job)

    def _run(self) -> None:
        while True:
            self.jobs.get().run()


def _extend_statistics(stats, first_ns: int, last_ns: int, count: int) -> None:
    """Count `count` messages logged from first_ns to last_ns into mcap's Statistics record."""
    if stats.message_count == 0:
        stats.message_start_time = first_ns
    else:
        stats.message_start_time = min(first_ns, stats.message_start_time)
    stats.message_end_time = max(last_ns, stats.message_end_time)
    stats.message_count += count


class _MessageIndex(MessageIndex):
    """
    mcap's MessageIndex record written in one pass (mcap writes 2 calls per entry).

    records holds the (log time, offset) tuples of write_records, in record order.
    """

    def write(self, stream) -> None:
        flat = [value for entry in self.records for value in entry]
        body = struct.pack(f'<{len(flat)}Q', *flat)
        stream.write(struct.pack('<BQHI', 7, 6 + len(body), self.channel_id, len(body)) + body)


def _flush_loop(ref: Callable[[], BagWriter | None], stop: threading.Event, tick_s: float) -> None:
    """
    Flush in the background: wake every tick_s and flush a writer whose oldest message is due.

    The oldest unflushed message is the one that counts. Ends when the writer is closed or
    garbage-collected.
    """
    while not stop.wait(tick_s):
        writer = ref()
        if writer is None or writer._closed:
            return
        try:
            writer.flush_if_due()
        except (
            BagError,
            ValueError,
            OSError,
        ):  # closed meanwhile, or the disk is gone: close() reports it
            return
        finally:
            del writer


def _weak_close(writer: BagWriter) -> Callable[[], None]:
    ref = weakref.ref(writer)

    def close() -> None:
        w = ref()
        if w is not None:
            w.close()

    return close


def _redeliver(signum: int, handler: Any = None) -> None:
    """
    Act on signum as the handler in place before ours would have.

    That is KeyboardInterrupt for SIGINT, termination for SIGTERM, so the process exits the way it
    would have without the bag. A Python handler is called here, synchronously: re-raising the
    signal from inside a handler would only queue it, and the interrupted code would run on against
    the closed bag first.
    """
    if callable(handler):
        handler(signum, None)
    else:
        signal.raise_signal(signum)


def qos_profiles_yaml(profiles: Iterable[Any]) -> str:
    """
    Return rosbag2's `offered_qos_profiles` YAML for rclpy QoSProfile objects; '' for none.

    The objects come e.g. from node.get_publishers_info_by_topic(t)[i].qos_profile.
    """

    def duration(d: Any) -> dict[str, int]:
        ns = int(getattr(d, 'nanoseconds', 0))
        if ns <= 0 or ns >= 2**63 - 1:  # infinite / unset: rosbag2 writes RMW_DURATION_INFINITE
            return {'sec': 9223372036, 'nsec': 854775807}
        return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}

    def policy(p: Any) -> str:
        return getattr(p, 'name', str(p)).lower()

    items = [
        {
            'history': policy(p.history),
            'depth': int(p.depth),
            'reliability': policy(p.reliability),
            'durability': policy(p.durability),
            'deadline': duration(p.deadline),
            'lifespan': duration(p.lifespan),
            'liveliness': policy(p.liveliness),
            'liveliness_lease_duration': duration(p.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(p.avoid_ros_namespace_conventions),
        }
        for p in profiles
    ]
    return yaml.safe_dump(items, sort_keys=False).strip() if items else ''


def install_signal_handlers(
    writer: BagWriter, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
) -> Callable[[], None]:
    """
    Close `writer` on SIGINT/SIGTERM, then let the signal act as before (KeyboardInterrupt, exit).

    Call from the main thread. If the signal lands while this thread is inside writer.write(), the
    close is deferred to the end of that write so no record is cut in half. Returns a function
    restoring the previous handlers. Not for processes where rclpy owns the signals (ROS nodes):
    there, close the writer in a `finally` after spin returns.
    """
    # a signal the process ignores (e.g. SIGINT in a background job) stays ignored: closing the bag
    # on it would leave the process writing to a closed bag
    signals = tuple(s for s in signals if signal.getsignal(s) is not signal.SIG_IGN)
    previous = {s: signal.getsignal(s) for s in signals}
    writer._previous_handlers = dict(previous)

    def restore() -> None:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)

    def handler(signum: int, frame: FrameType | None) -> None:
        restore()
        if writer._busy_thread == threading.get_ident():
            writer._pending_signal = signum
            return
        writer.close()
        _redeliver(signum, previous.get(signum))

    for s in signals:
        signal.signal(s, handler)
    return restore
