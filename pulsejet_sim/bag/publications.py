"""
A run's publications as MCAP Message records, laid out a stretch at a time.

The offline runner publishes the same messages at every publication period, in sim_node's order:
each actuator's command (std_msgs/Float64), the applied command when it changed
(sensor_msgs/JointState), the state topics (bag.cdr.TopicEncoder.observation's order), the mantle
profile and, every LEDGER_PERIOD_S, the energy ledger. Every one of them but the ledger has one
size for a whole run (fixed frame ids, names and point counts), so the records of a stretch of
publications are copies of one template with the varying fields (sequence, log and publish time,
header stamp, values) written over them, for the whole stretch in one call of a numba kernel
(bag.publication_kernel), no Python object per message. A record is the MCAP Message record
(opcode 5, length, channel, sequence, log time, publish time = log time) followed by the bytes
bag.cdr.TopicEncoder writes for the same message (test_recording compares them message by
message).

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
        # the kernel's arguments (publication_kernel.lay_out), as arrays
        self._c_starts = np.array(self.command.starts, dtype=np.int64)
        self._c_columns = np.array(self.command_columns, dtype=np.int64)
        self._s_starts = np.array(self.state.starts, dtype=np.int64)
        self._stamp_ats = np.array(self.state_stamps, dtype=np.int64)
        self._value_ats = np.array([at for at, _ in self.state_values], dtype=np.int64)
        self._value_columns = np.array([c for _, c in self.state_values], dtype=np.int64)
        self._profile_at = self.profile_at if profile_points is not None else 0
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
        from pulsejet_sim.bag.publication_kernel import lay_out

        n = len(state_ns)
        commanded = command_ns >= 0
        applied = applied & commanded
        counts = dict(self.counts)  # committed by the caller (a stretch may be laid out twice)
        c_part, a_part, s_part = self.command, self.applied, self.state
        n_commanded, n_applied = int(commanded.sum()), int(applied.sum())
        # the ledgers' bytes back to back, publication row's between bounds[row] and [row + 1]
        ledger_rows = sorted(ledgers)
        sizes = np.zeros(n + 1, dtype=np.int64)
        sizes[1:][ledger_rows] = [len(ledgers[row]) for row in ledger_rows]
        bounds = np.cumsum(sizes)
        ledger_data = np.frombuffer(b''.join(ledgers[row] for row in ledger_rows), np.uint8)
        out = np.empty(
            n_commanded * c_part.width + n_applied * a_part.width + n * s_part.width
            + _HEAD.size * len(ledger_rows) + len(ledger_data), dtype=np.uint8,
        )
        index_c = np.empty((len(c_part.starts), n_commanded, 2), dtype='<u8')
        index_a = np.empty((n_applied, 2), dtype='<u8')
        index_s = np.empty((len(s_part.starts), n, 2), dtype='<u8')
        index_l = np.empty((len(ledger_rows), 2), dtype='<u8')
        if self.profile_points is not None:
            r_m, z_m = (np.ascontiguousarray(p, dtype=np.float64) for p in profiles)
        else:
            r_m = z_m = np.zeros((n, 0))
        channel = self.ledger_channel
        size, *_ = lay_out(
            out, c_part.template, self._c_starts, self._c_columns,
            np.array([counts[c] for c in c_part.channels], dtype=np.int64),
            a_part.template, self.applied_positions, counts[a_part.channels[0]],
            s_part.template, self._s_starts,
            np.array([counts[c] for c in s_part.channels], dtype=np.int64),
            self._stamp_ats, self._value_ats, self._value_columns, self._profile_at,
            commanded, applied, np.ascontiguousarray(command_ns, dtype=np.int64),
            np.ascontiguousarray(commands, dtype=np.float64),
            np.ascontiguousarray(state_ns, dtype=np.int64),
            np.ascontiguousarray(states, dtype=np.float64), r_m, z_m,
            ledger_data, bounds, channel, counts[channel],
            index_c, index_a, index_s, index_l,
        )
        assert size == len(out)
        # -- message indexes (log time, offset), channels in order of first appearance
        index = []
        if n_commanded:
            index += [(int(t[0, 1]), c, t) for c, t in zip(c_part.channels, index_c)]
        if n_applied:
            index.append((int(index_a[0, 1]), a_part.channels[0], index_a))
        index += [(int(t[0, 1]), c, t) for c, t in zip(s_part.channels, index_s)]
        if ledger_rows:
            index.append((int(index_l[0, 1]), channel, index_l))
        index.sort(key=lambda entry: entry[0])
        for _, c, t in index:
            counts[c] += len(t)
        times = [int(state_ns[0]), int(state_ns[-1])]
        if n_commanded:
            times += [int(index_c[0, 0, 0]), int(index_c[0, -1, 0])]
        return Stretch(
            records=[out],
            size=size,
            index=[(channel, table) for _, channel, table in index],
            first_ns=min(times),
            last_ns=max(times),
            counts=counts,
        )


def warm_kernel() -> None:
    """
    Compile (or load from numba's cache) the recording's kernels, with a run's argument types.

    publication_kernel's lay_out and stamps_and_changes. `make venv` calls it, so the first
    `pulsejet run` does not compile them.
    """
    from pulsejet_sim.bag.cdr import RECORDED_TOPICS
    from pulsejet_sim.bag.publication_kernel import stamps_and_changes

    # the runner's rows: read-only doubles (np.frombuffer of the packed publications)
    columns = 2 + len(APPLIED_COMMAND_NAMES) + len(STATE_FIELDS)
    rows = np.frombuffer(np.zeros((2, columns)).tobytes()).reshape(2, columns)
    stamps_and_changes(rows, 1 + len(APPLIED_COMMAND_NAMES), np.zeros(3), False)

    layout = PublicationLayout({topic: i for i, topic in enumerate(RECORDED_TOPICS)}, 3)
    layout.records(
        np.array([-1, 0]), np.zeros((2, len(APPLIED_COMMAND_NAMES))), np.ones(2, dtype=bool),
        np.array([0, 10]), np.zeros((2, len(STATE_FIELDS))), (np.zeros((2, 3)), np.zeros((2, 3))),
        {1: layout.encoder.ledger({'in_initial': 1.0}, 10)},
    )
