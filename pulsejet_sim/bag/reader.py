"""Read pulsejet MCAP recordings without rclpy: messages are decoded from the definitions stored in
the file (mcap_ros2), so a recording stays readable on a machine without the ROS packages.

The file is read front to back, record by record. That also reads a file whose writer was killed
hard (no summary, last chunk cut short): everything up to the last complete chunk is returned and
`BagInfo.truncated` says so; repair() rewrites such a file into a complete, indexed one.
"""
from __future__ import annotations

import struct
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

MCAP_MAGIC = b'\x89MCAP0\r\n'

# Types whose scalar load_series extracts: type name -> attribute path of the value.
SCALAR_FIELDS: dict[str, tuple[str, ...]] = {
    'std_msgs/msg/Float64': ('data',),
    'geometry_msgs/msg/TwistStamped': ('twist', 'linear', 'x'),
    'geometry_msgs/msg/WrenchStamped': ('wrench', 'force', 'x'),
}
CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'


class BagReadError(ValueError):
    """A file that is missing, not an MCAP, or not a ROS 2 (profile `ros2`) recording; names the file."""


class BagMessage(NamedTuple):
    topic: str          # qualified name as stored, e.g. '/pulsejet/velocity'
    type_name: str      # e.g. 'geometry_msgs/msg/TwistStamped'
    log_time_ns: int    # receive time (recorder) or simulation time (offline runner), ns
    msg: Any            # decoded message (attribute access like the rclpy class)


@dataclass
class BagInfo:
    """What a full read of the file found."""

    path: Path
    profile: str = ''
    topics: dict[str, str] = field(default_factory=dict)         # topic -> type name
    counts: dict[str, int] = field(default_factory=dict)         # topic -> messages
    definitions: dict[str, str] = field(default_factory=dict)    # type name -> ros2msg text
    truncated: bool = False                                      # no footer: writer killed hard


def _open_checked(path: str | Path) -> tuple[Path, Any]:
    p = Path(path)
    if not p.exists():
        raise BagReadError(f'{str(p)!r}: no such file; expected an MCAP recording (.mcap)')
    if p.is_dir():
        raise BagReadError(f'{str(p)!r} is a directory; expected an MCAP recording file (.mcap)')
    fh = open(p, 'rb')
    magic = fh.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        fh.close()
        what = 'an empty file' if not magic else 'not an MCAP file (bad magic bytes)'
        raise BagReadError(f'{str(p)!r} is {what}; expected an MCAP recording (.mcap)')
    fh.seek(0)
    return p, fh


def _records(fh: Any, info: BagInfo) -> Iterator[Any]:
    """Records in file order; stops quietly at a cut-off tail and flags the file as truncated."""
    reader = StreamReader(fh, skip_magic=False, record_size_limit=1 << 31)
    it = reader.records
    footer_seen = False
    while True:
        try:
            record = next(it)
        except StopIteration:
            break
        except (McapError, struct.error, EOFError, zlib.error, ValueError, RuntimeError, MemoryError):
            # A record cut short by a hard kill (or a corrupt chunk): keep what was complete.
            break
        if isinstance(record, Footer):
            footer_seen = True
        yield record
    info.truncated = not footer_seen


def iter_bag(path: str | Path, topics: Iterable[str] | None = None,
             info: BagInfo | None = None, decode: bool = True,
             types: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Messages in file order as BagMessage; `topics` filters by name ('pulsejet/x' or '/pulsejet/x'),
    `types` by type name (skipped messages are counted in `info` but not decoded).

    decode=False yields the raw CDR bytes as `msg`. Fills `info` (if given) while reading.
    Raises BagReadError for a missing file, a non-MCAP file or a non-ros2 profile.
    """
    p, fh = _open_checked(path)
    info = info if info is not None else BagInfo(p)
    info.path = p
    wanted = None if topics is None else {t if t.startswith('/') else '/' + t for t in topics}
    wanted_types = None if types is None else set(types)
    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    try:
        for record in _records(fh, info):
            if isinstance(record, Header):
                info.profile = record.profile
                if record.profile != 'ros2':
                    raise BagReadError(f'{str(p)!r} is an MCAP file with profile {record.profile!r}; '
                                       'expected a ROS 2 recording (profile "ros2")')
            elif isinstance(record, Schema):
                schemas[record.id] = record
                info.definitions[record.name] = record.data.decode('utf-8', 'replace')
            elif isinstance(record, Channel):
                channels[record.id] = record
                schema = schemas.get(record.schema_id)
                info.topics[record.topic] = schema.name if schema else ''
                info.counts.setdefault(record.topic, 0)
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    continue  # its channel record was lost with a truncated chunk
                info.counts[channel.topic] = info.counts.get(channel.topic, 0) + 1
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
                        decoder = factory.decoder_for(channel.message_encoding, schema)
                        if decoder is None:
                            raise BagReadError(
                                f'{str(p)!r}: topic {channel.topic!r} has encoding '
                                f'{channel.message_encoding!r} / schema {type_name!r} that cannot be decoded; '
                                'expected cdr with a ros2msg schema')
                        decoders[channel.id] = decoder
                    msg = decoder(record.data)
                yield BagMessage(channel.topic, type_name, record.log_time, msg)
    finally:
        fh.close()


def read_bag(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, Any]]:
    """Yield (topic, type_name, log_time_ns, msg) for every message, in file order."""
    yield from iter_bag(path, topics)


def bag_info(path: str | Path) -> BagInfo:
    """Topics, types, counts and definitions of a file (reads it once without decoding)."""
    info = BagInfo(Path(path))
    for _ in iter_bag(path, info=info, decode=False):
        pass
    return info


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def find_topic(names: Iterable[str], relative: str) -> str | None:
    """The stored topic for a relative name: '/pulsejet/velocity' or a namespaced '/ns/pulsejet/velocity'."""
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


def load_series(path: str | Path, info: BagInfo | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Scalar time series of every Float64 / TwistStamped / WrenchStamped / Clock topic in the file.

    Returns {qualified topic: (t_s, value)} sorted by time. Values: Float64 `.data`, TwistStamped
    `.twist.linear.x`, WrenchStamped `.wrench.force.x`, Clock: simulation time in s. Times: the
    header stamp (simulation time) where the message has a header; otherwise the log time, mapped
    onto simulation time through the recorded /clock messages when there are any (a live recorder
    logs wall-clock receive times), else the log time itself in s.
    """
    raw: dict[str, tuple[list[float], list[float], bool]] = {}
    for topic, type_name, log_ns, msg in iter_bag(path, info=info, types=[*SCALAR_FIELDS, CLOCK_TYPE]):
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

    clock_topic = next((t for t, (_, _, stamped) in raw.items()
                        if t.endswith('/clock') and not stamped), None)
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
    """Function mapping log times (s) to simulation time (s) by interpolating the /clock samples
    (receive time -> carried time); outside their span it continues at the real-time rate."""
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


def repair(path: str | Path, out_path: str | Path | None = None) -> Path:
    """Rewrite a recording whose writer was killed hard into a complete file (summary, indexes).

    Keeps every message up to the last complete chunk and the definitions stored in the file.
    Default output: `<name>.repaired.mcap` next to the input. Returns the output path.
    """
    from pulsejet_sim.bag.writer import BagWriter  # local: the reader must not need the writer
    src = Path(path)
    out = Path(out_path) if out_path is not None else src.with_name(src.stem + '.repaired.mcap')
    if out.resolve() == src.resolve():
        raise BagReadError(f'repair output {str(out)!r} must differ from the input file')
    info = BagInfo(src)
    messages = list(iter_bag(src, info=info, decode=False))
    with BagWriter(out) as bag:
        for topic, type_name in info.topics.items():
            bag.add_topic(topic, type_name, definition=info.definitions.get(type_name))
        for m in messages:
            bag.write(m.topic, m.msg, m.log_time_ns)
    if not info.truncated:
        warnings.warn(f'{str(src)!r} was already complete; rewrote it anyway', stacklevel=2)
    return out
