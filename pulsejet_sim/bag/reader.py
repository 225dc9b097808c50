"""
Read pulsejet MCAP recordings without rclpy.

Messages are decoded from the definitions stored in the file (mcap_ros2), so a recording stays
readable on a machine without the ROS packages.

The file is read front to back, record by record, with its own framing checks (never the index,
never a length it cannot verify). That also reads a file whose writer was killed hard (no summary,
last chunk cut short) or that was damaged afterwards: everything that can be read is returned, a
chunk that fails its CRC or cannot be decompressed is skipped, a message that cannot be decoded is
skipped and counted, and `BagInfo` says what was cut (`truncated`, `bytes_dropped`,
`corrupt_chunks`, `undecodable`). `pulsejet repair` (bag.repair) rewrites such a file into a
complete, indexed one that every MCAP/rosbag2 reader opens.

A recording written by a newer pulsejet format (`pulsejet-format=N` in the MCAP header's library
field, N > FORMAT_VERSION) or a newer MCAP major version is refused with BagReadError.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Iterator

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
from pulsejet_sim.bag.records import (
    BagInfo,
    BagMessage,
    BagReadError,
    check_header,
    iter_records,
    open_checked,
)

# Types whose scalar load_series extracts: type name -> attribute path of the value.
SCALAR_FIELDS: dict[str, tuple[str, ...]] = {
    'std_msgs/msg/Float64': ('data',),
    'geometry_msgs/msg/TwistStamped': ('twist', 'linear', 'x'),
    'geometry_msgs/msg/WrenchStamped': ('wrench', 'force', 'x'),
}
CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'


def iter_bag(
    path: str | Path,
    topics: Iterable[str] | None = None,
    info: BagInfo | None = None,
    decode: bool = True,
    types: Iterable[str] | None = None,
) -> Iterator[BagMessage]:
    """
    Yield the messages in file order as BagMessage.

    `topics` filters by name ('pulsejet/x' or '/pulsejet/x'), `types` by type name (skipped
    messages are counted in `info` but not decoded).

    decode=False yields the raw CDR bytes as `msg`. Fills `info` (if given) while reading,
    including what was cut or skipped. Raises BagReadError for a missing file, a non-MCAP file, a
    non-ros2 profile or a recording of a newer pulsejet format; never for a damaged tail or a
    corrupt chunk (those are skipped and reported in `info`).
    """
    p, fh = open_checked(path)
    info = info if info is not None else BagInfo(p)
    info.path = p
    wanted = None if topics is None else {t if t.startswith('/') else '/' + t for t in topics}
    wanted_types = None if types is None else set(types)
    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    try:
        for record in iter_records(fh, info):
            if isinstance(record, Header):
                check_header(record, info, p)
            elif isinstance(record, Schema):
                # the first record of an id wins: a later copy (summary section) may be damaged
                record = schemas.setdefault(record.id, record)
                info.definitions.setdefault(record.name, record.data.decode('utf-8', 'replace'))
                info.schema_encodings.setdefault(record.name, record.encoding)
            elif isinstance(record, Channel):
                if record.id in channels:
                    continue  # the summary's copy of a channel already seen
                channels[record.id] = record
                schema = schemas.get(record.schema_id)
                info.topics[record.topic] = schema.name if schema else ''
                info.counts.setdefault(record.topic, 0)
                info.channel_metadata[record.topic] = dict(record.metadata)
                info.encodings[record.topic] = record.message_encoding
            elif isinstance(record, Metadata):
                info.metadata.append((record.name, dict(record.metadata)))
            elif isinstance(record, Attachment):
                info.attachments.append(record)
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    info.orphan_messages += 1  # its channel record was lost with a corrupt chunk
                    continue
                info.counts[channel.topic] = info.counts.get(channel.topic, 0) + 1
                t = record.log_time
                info.first_log_ns = t if info.first_log_ns is None else min(info.first_log_ns, t)
                info.last_log_ns = t if info.last_log_ns is None else max(info.last_log_ns, t)
                if wanted is not None and channel.topic not in wanted:
                    continue
                schema = schemas.get(channel.schema_id)
                type_name = schema.name if schema else ''
                if wanted_types is not None and type_name not in wanted_types:
                    continue
                msg: Any = record.data
                if decode:
                    decoder = decoders.get(channel.id)
                    if decoder is None:
                        try:
                            decoder = factory.decoder_for(channel.message_encoding, schema)
                        except Exception:  # a schema text that does not parse (damaged file)
                            decoder = None
                        if decoder is None:
                            if (
                                channel.message_encoding != 'cdr'
                                or schema is None
                                or schema.encoding != 'ros2msg'
                            ):
                                raise BagReadError(
                                    f'{str(p)!r}: topic {channel.topic!r} has encoding '
                                    f'{channel.message_encoding!r} / schema {type_name!r} that '
                                    'cannot be '
                                    'decoded; expected cdr with a ros2msg schema'
                                )
                            decoder = (
                                False  # a ros2msg schema that does not parse: skip its messages
                            )
                        decoders[channel.id] = decoder
                    if decoder is False:
                        info.undecodable[channel.topic] = (
                            info.undecodable.get(channel.topic, 0) + 1
                        )
                        continue
                    try:
                        msg = decoder(record.data)
                    except Exception:  # a message damaged inside an intact chunk
                        info.undecodable[channel.topic] = (
                            info.undecodable.get(channel.topic, 0) + 1
                        )
                        continue
                yield BagMessage(channel.topic, type_name, record.log_time, msg)
    finally:
        fh.close()


def read_bag(
    path: str | Path, topics: Iterable[str] | None = None
) -> Iterator[tuple[str, str, int, Any]]:
    """Yield (topic, type_name, log_time_ns, msg) for every message, in file order."""
    yield from iter_bag(path, topics)


def bag_info(path: str | Path) -> BagInfo:
    """
    Return topics, types, counts, channel metadata, metadata records, definitions and damage.

    Reads the file once without decoding.
    """
    info = BagInfo(Path(path))
    for _ in iter_bag(path, info=info, decode=False):
        pass
    return info


def read_metadata(path: str | Path, name: str | None = None) -> dict[str, str]:
    """
    Return the key/values of the MCAP metadata records called `name`, merged in file order.

    All records when `name` is None. Reads a damaged file as far as it can; BagReadError as
    iter_bag.
    """
    info = BagInfo(Path(path))
    for _ in iter_bag(path, info=info, decode=False, types=()):
        pass
    found: dict[str, str] = {}
    for record_name, values in info.metadata:
        if name is None or record_name == name:
            found.update(values)
    return found


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def find_topic(names: Iterable[str], relative: str) -> str | None:
    """
    Return the stored topic for a relative name.

    '/pulsejet/velocity' or a namespaced '/ns/pulsejet/velocity'.
    """
    rel = relative.lstrip('/')
    names = list(names)
    if '/' + rel in names:
        return '/' + rel
    matches = sorted(n for n in names if n.endswith('/' + rel))
    return matches[0] if matches else None


def _scalar(msg: Any, path: tuple[str, ...]) -> float:
    for attr in path:
        msg = getattr(msg, attr)
    return float(msg)


def load_series(
    path: str | Path, info: BagInfo | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """
    Scalar time series of every Float64 / TwistStamped / WrenchStamped / Clock topic in the file.

    Returns {qualified topic: (t_s, value)} sorted by time. Values: Float64 `.data`, TwistStamped
    `.twist.linear.x`, WrenchStamped `.wrench.force.x`, Clock: simulation time in s. Times: the
    header stamp (simulation time) where the message has a header; otherwise the log time, mapped
    onto simulation time through the recorded /clock messages when there are any (a live recorder
    logs wall-clock receive times), else the log time itself in s.
    """
    raw: dict[str, tuple[list[float], list[float], bool]] = {}
    for topic, type_name, log_ns, msg in iter_bag(
        path, info=info, types=[*SCALAR_FIELDS, CLOCK_TYPE]
    ):
        if type_name in SCALAR_FIELDS:
            value = _scalar(msg, SCALAR_FIELDS[type_name])
        elif type_name == CLOCK_TYPE:
            value = stamp_to_s(msg.clock)
        else:
            continue
        header = getattr(msg, 'header', None)
        t = stamp_to_s(header.stamp) if header is not None else log_ns * 1e-9
        times, values, _ = raw.setdefault(topic, ([], [], header is not None))
        times.append(t)
        values.append(value)

    clock_topic = next(
        (t for t, (_, _, stamped) in raw.items() if t.endswith('/clock') and not stamped), None
    )
    to_sim = _clock_map(raw[clock_topic][0], raw[clock_topic][1]) if clock_topic else None
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic, (times, values, stamped) in raw.items():
        t = np.asarray(times, dtype=float)
        v = np.asarray(values, dtype=float)
        if not stamped and to_sim is not None and topic != clock_topic:
            t = to_sim(t)
        order = np.argsort(t, kind='stable')
        series[topic] = (t[order], v[order])
    if clock_topic is not None:
        # The clock's own time axis is the simulation time it carries.
        sim = series[clock_topic][1]
        series[clock_topic] = (sim.copy(), sim)
    return series


def _clock_map(log_s: list[float], sim_s: list[float]) -> Any | None:
    """
    Return a function mapping log times (s) to simulation time (s).

    It interpolates the /clock samples (receive time -> carried time); outside their span it
    continues at the real-time rate.
    """
    if not log_s:
        return None
    order = np.argsort(log_s, kind='stable')
    lx = np.asarray(log_s, dtype=float)[order]
    sx = np.asarray(sim_s, dtype=float)[order]

    def to_sim(t: np.ndarray) -> np.ndarray:
        out = np.interp(t, lx, sx)
        before, after = t < lx[0], t > lx[-1]
        out[before] = sx[0] + (t[before] - lx[0])
        out[after] = sx[-1] + (t[after] - lx[-1])
        return out

    return to_sim
