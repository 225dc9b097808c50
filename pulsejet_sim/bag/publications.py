"""
A run's publications as MCAP Message records, laid out with numpy a stretch at a time.

The offline runner publishes the same messages at every publication period, in sim_node's order:
each actuator's command (std_msgs/Float64), the applied command when it changed
(sensor_msgs/JointState), the state topics (bag.cdr.TopicEncoder.observation's order), the mantle
profile and, every LEDGER_PERIOD_S, the energy ledger. Every one of them but the ledger has one
size for a whole run (fixed frame ids, names and point counts), so the records of a stretch of
publications are copies of one template with the varying fields (sequence, log and publish time,
header stamp, values) written over them: one numpy assignment per field for the whole stretch,
no Python object per message. A record is the MCAP Message record (opcode 5, length, channel,
sequence, log time, publish time = log time) followed by the bytes bag.cdr.TopicEncoder writes for
the same message (test_recording compares them message by message).

PublicationLayout.records returns the records of a stretch with each channel's message index;
BagWriter.write_chunk writes them as one MCAP chunk.
"""

from __future__ import annotations

from dataclasses import dataclass
import struct
from typing import Mapping, Sequence

import numpy as np
from pulsejet_sim.bag.cdr import ColumnEncoder, ENCAPSULATION, TopicEncoder
from pulsejet_sim.core.topics import (
    APPLIED_COMMAND_NAMES,
    COMMAND_FIELDS,
    COMMAND_TOPICS,
    TOPIC_APPLIED_COMMAND,
    TOPIC_CLOCK,
    TOPIC_ENERGY_LEDGER,
    TOPIC_FLUID_MASS,
    TOPIC_MANTLE_PROFILE,
    TOPIC_MANTLE_RADIUS,
    TOPIC_ODOMETRY,
    TOPIC_THRUST,
    TOPIC_VELOCITY,
    TOPIC_VOLUME,
)

#: the Observation fields the state topics carry, the columns of PublicationLayout.records'
#: state values in this order
STATE_FIELDS = (
    'mantle_radius_m', 'volume_m3', 'velocity_m_s', 'thrust_n', 'fluid_mass_kg', 'position_m'
)
#: the state topics in the order sim_node publishes them (TopicEncoder.observation)
STATE_ORDER = (
    TOPIC_MANTLE_RADIUS, TOPIC_VOLUME, TOPIC_VELOCITY, TOPIC_THRUST, TOPIC_FLUID_MASS,
    TOPIC_ODOMETRY, TOPIC_CLOCK,
)
# MCAP Message record head: opcode u8, record length u64 (what follows it), channel u16,
# sequence u32, log time u64, publish time u64; the message bytes follow
_HEAD = struct.Struct('<BQHIQQ')
_SEQUENCE = 11
_HEAD_TAIL = np.dtype([('sequence', '<u4'), ('log_time', '<u8'), ('publish_time', '<u8')])
# in a message: the Header (or Clock) stamp, int32 s then uint32 ns, after the encapsulation
_STAMP = 4


@dataclass(frozen=True)
class Stretch:
    """
    The records of a stretch of publications, ready for BagWriter.write_chunk.

    records: the Message records back to back, as a list of bytes-like objects (bytes,
    memoryviews; the file holds them joined) of size bytes in all; index: (channel id, (k, 2)
    uint64 array of log time and offset in records) per channel, in order of first appearance;
    first_ns, last_ns: the smallest and largest log time; counts: each channel's message count
    after it (the layout's counts to continue from once the stretch is written).
    """

    records: list
    size: int
    index: list[tuple[int, np.ndarray]]
    first_ns: int
    last_ns: int
    counts: dict[int, int]


class _Part:
    """Messages always written together: one template row (heads and bytes), where each starts."""

    def __init__(self, messages: Sequence[tuple[str, bytes]], channels: Mapping[str, int]):
        self.topics = [topic for topic, _ in messages]
        self.channels = [channels[topic] for topic in self.topics]
        self.starts: list[int] = []  # record start within the part
        template = b''
        for topic, data in messages:
            self.starts.append(len(template))
            template += _HEAD.pack(5, _HEAD.size - 9 + len(data), channels[topic], 0, 0, 0) + data
        self.template = np.frombuffer(template, dtype=np.uint8)
        self.width = len(template)

    def rows(self, n: int) -> np.ndarray:
        rows = np.empty((n, self.width), dtype=np.uint8)
        rows[:] = self.template
        return rows


def _bytes(column: np.ndarray, dtype: str) -> np.ndarray:
    """Return a column of n values (or an (n, k) block) as an (n, bytes) uint8 array."""
    column = np.ascontiguousarray(column, dtype=dtype)
    return column.view(np.uint8).reshape(len(column), -1)


class PublicationLayout:
    """
    The records of the offline runner's publications for fixed channels and frame ids.

    channels: channel id of each recorded topic (the command topics, the applied command, the
    state topics, the energy ledger, and the mantle profile if the model has one);
    profile_points: the profile's point count (None: no profile topic). Keeps each channel's
    message count (counts: set it to each written stretch's counts), so sequences continue from
    stretch to stretch (1 for a channel's first message).
    """

    def __init__(
        self,
        channels: Mapping[str, int],
        profile_points: int | None,
        encoder: TopicEncoder | None = None,
    ) -> None:
        columns = ColumnEncoder(encoder)
        enc = columns.encoder
        self.encoder = enc
        float64 = ENCAPSULATION + b'\x00' * 8
        self.command = _Part([(topic, float64) for topic in COMMAND_TOPICS], channels)
        self.command_columns = [
            APPLIED_COMMAND_NAMES.index(COMMAND_FIELDS[topic]) for topic in COMMAND_TOPICS
        ]
        self.applied = _Part([(TOPIC_APPLIED_COMMAND, columns._joint_state)], channels)
        self.applied_positions = _HEAD.size + columns._joint_state_positions
        state = [
            (TOPIC_MANTLE_RADIUS, float64), (TOPIC_VOLUME, float64),
            (TOPIC_VELOCITY, columns._vector6), (TOPIC_THRUST, columns._vector6),
            (TOPIC_FLUID_MASS, float64), (TOPIC_ODOMETRY, columns._odometry),
            (TOPIC_CLOCK, float64),
        ]
        self.profile_points = profile_points
        if profile_points is not None:
            zeros = np.zeros(profile_points)
            state.append((TOPIC_MANTLE_PROFILE, enc.profile(zeros, zeros, 0)))
        self.state = _Part(state, channels)
        at = dict(zip(self.state.topics, self.state.starts))
        body = _HEAD.size
        # (byte offset in the state part, STATE_FIELDS column) of each value a state topic carries
        self.state_values = [
            (at[TOPIC_MANTLE_RADIUS] + body + 4, 0),
            (at[TOPIC_VOLUME] + body + 4, 1),
            (at[TOPIC_VELOCITY] + body + columns._vector6_x, 2),
            (at[TOPIC_THRUST] + body + columns._vector6_x, 3),
            (at[TOPIC_FLUID_MASS] + body + 4, 4),
            (at[TOPIC_ODOMETRY] + body + columns._odometry_x, 5),
            (at[TOPIC_ODOMETRY] + body + columns._odometry_vx, 2),
        ]
        stamped = [TOPIC_VELOCITY, TOPIC_THRUST, TOPIC_ODOMETRY, TOPIC_CLOCK]
        if profile_points is not None:
            stamped.append(TOPIC_MANTLE_PROFILE)
            self.profile_at = self.state.width - 12 * profile_points
        self.state_stamps = [at[topic] + body + _STAMP for topic in stamped]
        self.ledger_channel = channels[TOPIC_ENERGY_LEDGER]
        self.template = np.concatenate([self.command.template, self.state.template])
        self.counts = dict.fromkeys(channels.values(), 0)

    def records(
        self,
        command_ns: np.ndarray,
        commands: np.ndarray,
        applied: np.ndarray,
        state_ns: np.ndarray,
        states: np.ndarray,
        profiles: tuple[np.ndarray, np.ndarray] | None,
        ledgers: Mapping[int, bytes],
    ) -> Stretch:
        """
        Return the records of n publications, in order, each in sim_node's order.

        command_ns: (n,) int64 stamps of the commands, -1 for a publication without commands
        (the initial state, the state after a fault); commands: (n, 3) values in
        APPLIED_COMMAND_NAMES' order; applied: (n,) bool, the applied command published too;
        state_ns: (n,) stamps of the state; states: (n, 6) values, STATE_FIELDS' columns;
        profiles: (r_m, z_m), each (n, profile_points), or None without a profile topic;
        ledgers: publication row -> the energy ledger's CDR bytes (TopicEncoder.ledger).
        """
        n = len(state_ns)
        commanded = command_ns >= 0
        applied = applied & commanded
        counts = dict(self.counts)  # committed by the caller (a stretch may be laid out twice)
        c_part, a_part, s_part = self.command, self.applied, self.state
        wc, wa, ws = c_part.width, a_part.width, s_part.width
        # -- a row per publication: its commands then its state (a row without commands uses
        # only the state's columns)
        rows = np.empty((n, wc + ws), dtype=np.uint8)
        rows[:] = self.template
        c_ns = command_ns[commanded]
        c_seq = np.cumsum(commanded, dtype=np.int64)
        for start, channel, heads in _heads(c_part, counts, c_seq, command_ns):
            rows[:, start + _SEQUENCE:start + _HEAD.size] = heads
        values = _bytes(commands, '<f8')  # each value's 8 bytes, one conversion for all
        for start, column in zip(c_part.starts, self.command_columns):
            rows[:, start + _HEAD.size + 4:start + _HEAD.size + 12] = values[
                :, 8 * column:8 * column + 8
            ]
        s_seq = np.arange(1, n + 1, dtype=np.int64)
        for start, channel, heads in _heads(s_part, counts, s_seq, state_ns):
            rows[:, wc + start + _SEQUENCE:wc + start + _HEAD.size] = heads
        stamps = _stamps(state_ns)
        for at in self.state_stamps:
            rows[:, wc + at:wc + at + 8] = stamps
        values = _bytes(states, '<f8')
        for at, column in self.state_values:
            rows[:, wc + at:wc + at + 8] = values[:, 8 * column:8 * column + 8]
        if self.profile_points is not None:
            r_m, z_m = profiles
            points = np.zeros((n, self.profile_points, 3), dtype='<f4')
            points[:, :, 0] = z_m  # Point32 x = axial position, y = radius (TopicEncoder.profile)
            points[:, :, 1] = r_m
            rows[:, wc + self.profile_at:] = points.reshape(n, -1).view(np.uint8)
        # -- the applied command, only where published
        a_rows = a_part.rows(int(applied.sum()))
        if len(a_rows):
            a_ns = command_ns[applied]
            for start, channel, heads in _heads(
                a_part, counts, np.arange(1, len(a_ns) + 1), a_ns
            ):
                a_rows[:, _SEQUENCE:_HEAD.size] = heads
            a_rows[:, _HEAD.size + _STAMP:_HEAD.size + _STAMP + 8] = _stamps(a_ns)
            at = self.applied_positions
            a_rows[:, at:at + 24] = _bytes(commands[applied], '<f8')
        # -- the energy ledgers, one record each
        ledger_rows = sorted(ledgers)
        ledger_records = {}
        channel = self.ledger_channel
        for row in ledger_rows:
            data = ledgers[row]
            counts[channel] += 1
            ns = int(state_ns[row])
            ledger_records[row] = (
                _HEAD.pack(5, _HEAD.size - 9 + len(data), channel, counts[channel], ns, ns) + data
            )
        # -- publication p: [commands] [applied] state [ledger], back to back: the rows of plain
        # publications (commands, no applied command, no ledger) are copied a stretch at a time
        special = ~commanded | applied
        special[ledger_rows] = True
        # slices of the rows' bytes (memoryviews: a slice costs no numpy call)
        width = wc + ws
        flat = memoryview(rows).cast('B')
        a_flat = memoryview(a_rows).cast('B') if len(a_rows) else None
        is_commanded, is_applied = commanded.tolist(), applied.tolist()
        pieces, done, a_row = [], 0, 0
        for row in np.flatnonzero(special).tolist():
            if row > done:
                pieces.append(flat[done * width:row * width])
            at = row * width
            if not is_commanded[row]:
                pieces.append(flat[at + wc:at + width])
            elif is_applied[row]:  # every applied row is special: a_row counts them in order
                pieces += [flat[at:at + wc], a_flat[a_row * wa:(a_row + 1) * wa],
                           flat[at + wc:at + width]]
                a_row += 1
            else:
                pieces.append(flat[at:at + width])
            if row in ledger_records:
                pieces.append(ledger_records[row])
            done = row + 1
        if done < n:
            pieces.append(flat[done * width:])
        size = sum(map(len, pieces))
        # -- message indexes (log time, offset), channels in order of first appearance
        sizes = commanded * wc + applied * wa + ws
        if ledger_rows:
            sizes[ledger_rows] += [len(ledger_records[row]) for row in ledger_rows]
        ends = np.cumsum(sizes)
        starts = ends - sizes
        index = []
        c_starts = starts[commanded]
        if len(c_starts):
            tables = np.empty((len(c_part.starts), len(c_starts), 2), dtype='<u8')
            tables[:, :, 0] = c_ns
            tables[:, :, 1] = c_starts + np.array(c_part.starts)[:, None]
            first = int(c_starts[0])
            index += [
                (first + at, c, t) for at, c, t in zip(c_part.starts, c_part.channels, tables)
            ]
            counts.update((c, counts[c] + len(c_starts)) for c in c_part.channels)
        if len(a_rows):
            table = np.stack([command_ns[applied], starts[applied] + wc], axis=1).astype('<u8')
            index.append((int(table[0, 1]), a_part.channels[0], table))
            counts[a_part.channels[0]] += len(table)
        tables = np.empty((len(s_part.starts), n, 2), dtype='<u8')
        tables[:, :, 0] = state_ns
        s_base = starts + commanded * wc + applied * wa
        tables[:, :, 1] = s_base + np.array(s_part.starts)[:, None]
        first = int(s_base[0])
        index += [(first + at, c, t) for at, c, t in zip(s_part.starts, s_part.channels, tables)]
        counts.update((c, counts[c] + n) for c in s_part.channels)
        if ledger_rows:
            table = np.empty((len(ledger_rows), 2), dtype='<u8')
            table[:, 0] = state_ns[ledger_rows]
            table[:, 1] = ends[ledger_rows] - [len(ledger_records[r]) for r in ledger_rows]
            index.append((int(table[0, 1]), channel, table))
        index.sort(key=lambda entry: entry[0])
        times = [int(state_ns[0]), int(state_ns[-1])]
        if len(c_ns):
            times += [int(c_ns[0]), int(c_ns[-1])]
        return Stretch(
            records=pieces,
            size=size,
            index=[(channel, table) for _, channel, table in index],
            first_ns=min(times),
            last_ns=max(times),
            counts=counts,
        )


def _heads(part: _Part, counts: Mapping[int, int], sequence: np.ndarray, log_ns: np.ndarray):
    """
    Yield (record start, channel, (n, 20) bytes of sequence, log and publish time) per record.

    sequence: 1, 2, ... counting the part's messages; each channel's count is added (one block
    for the channels whose counts agree, as a part's always do when only it writes them).
    """
    block = np.empty(len(log_ns), dtype=_HEAD_TAIL)
    block['log_time'] = log_ns
    block['publish_time'] = log_ns
    done = None
    for start, channel in zip(part.starts, part.channels):
        if done != counts[channel]:
            done = counts[channel]
            block['sequence'] = done + sequence
            heads = block.view(np.uint8).reshape(len(log_ns), _HEAD_TAIL.itemsize)
        yield start, channel, heads


def _stamps(ns: np.ndarray) -> np.ndarray:
    """builtin_interfaces/Time of each stamp in ns: int32 s, uint32 ns, as (n, 8) uint8."""
    both = np.empty((len(ns), 2), dtype='<i4')
    both[:, 0] = ns // 1_000_000_000
    both[:, 1] = ns % 1_000_000_000  # below 2^31: the same bytes as uint32
    return both.view(np.uint8).reshape(len(ns), 8)
