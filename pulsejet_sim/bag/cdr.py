"""
CDR bytes of the pulsejet topics straight from simulation values, without rclpy.

The offline tools (`pulsejet run`, sweeps, fits, optimisation and re-simulation that record) write
the same topics, types, frames and stamps as sim_node (ros/messages.py builds those as rclpy
objects). Building an rclpy message per sample and serialising it costs more than the physics
(101 Point32 objects per mantle profile), so this module packs the bytes directly: fixed-size
messages through precomputed `struct` layouts, sequences from numpy arrays.

Encoding: the ROS 2 default, plain CDR (XCDR1) little endian, as rmw_fastrtps / rmw_cyclonedds
write it (OMG DDS-XTypes 1.3, 7.4.3.5 "CDR": each primitive aligned to its own size, counted
from the end of the 4-byte encapsulation header `00 01 00 00`; a string is its uint32 length
including the NUL, its bytes and the NUL; a sequence is its uint32 count and its elements).
Padding is written as zeros (rclpy's Fast-CDR leaves padding bytes as they were in memory); every
other byte is the one `rclpy.serialization.serialize_message` writes for the equivalent message
(test_cdr.py compares them field by field).

No ROS import: frame ids, topic names and thresholds come from pulsejet_sim.core.topics.
"""

from __future__ import annotations

import math
import struct
from typing import Iterable, Mapping, Sequence

import numpy as np
from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.core.topics import (
    APPLIED_COMMAND_NAMES,
    BASE_FRAME_ID,
    COMMAND_FIELDS,
    COMMAND_TOPICS,
    FRAME_ID,
    LEDGER_HARDWARE_ID,
    LEDGER_STATUS_NAME,
    LEDGER_WARN_RELATIVE,
    ODOM_FRAME_ID,
    STATE_TOPICS,
    TOPIC_APPLIED_COMMAND,
    TOPIC_CLOCK,
    TOPIC_ENERGY_LEDGER,
    TOPIC_FLUID_MASS,
    TOPIC_MANTLE_PROFILE,
    TOPIC_MANTLE_RADIUS,
    TOPIC_ODOMETRY,
    TOPIC_THRUST,
    TOPIC_TYPES,
    TOPIC_VELOCITY,
    TOPIC_VOLUME,
)

ENCAPSULATION = b'\x00\x01\x00\x00'  # CDR, little endian, no options
# diagnostic_msgs/DiagnosticStatus levels (byte constants of the .msg)
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2
_MAX_STAMP_S = 2.0**31
_UINT32 = struct.Struct('<I')
_PADS = (b'', b'\x00', b'\x00\x00', b'\x00\x00\x00')
_STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: int32 s, uint32 ns


def stamp_ns(time_s: float) -> int:
    """
    Return simulation time in s as integer ns, rounded (builtin_interfaces/Time resolution).

    ValueError names a time outside [0, 2^31) s (not representable as a ROS Time).
    """
    t = float(time_s)
    if not math.isfinite(t) or t < 0.0 or t >= _MAX_STAMP_S:
        raise ValueError(f'time_s={time_s!r} rejected; allowed: a finite time in [0, 2^31) s')
    return round(t * 1e9)


def _string(text: str) -> bytes:
    """CDR string body: uint32 length with the NUL, the UTF-8 bytes, the NUL (4-aligned start)."""
    data = text.encode('utf-8') + b'\x00'
    return struct.pack('<I', len(data)) + data


_LEDGER_NAME = _string(LEDGER_STATUS_NAME)
_LEDGER_HARDWARE_ID = _string(LEDGER_HARDWARE_ID)


class _Layout:
    """
    A struct format for a message whose only variable parts are fixed-size fields.

    Tracks the offset from the end of the encapsulation header to insert CDR's alignment padding
    ('x' pad bytes, which struct writes as zeros).
    """

    def __init__(self) -> None:
        self.fmt = '<'
        self.offset = 0

    def align(self, size: int) -> None:
        pad = -self.offset % size
        if pad:
            self.fmt += f'{pad}x'
            self.offset += pad

    def add(self, code: str, size: int, count: int = 1) -> None:
        self.align(size)
        self.fmt += f'{count}{code}' if count != 1 else code
        self.offset += size * count

    def raw(self, data: bytes, alignment: int = 4) -> None:
        """Constant bytes (e.g. a string body) packed from an 's' argument."""
        self.align(alignment)
        self.fmt += f'{len(data)}s'
        self.offset += len(data)

    def header(self, frame: bytes) -> None:
        """std_msgs/Header: stamp (int32 sec, uint32 nanosec) and the frame id string."""
        self.add('i', 4)
        self.add('I', 4)
        self.raw(frame)

    def to_struct(self) -> struct.Struct:
        return struct.Struct(self.fmt)


class _Writer:
    """Variable-length CDR body (sequences, strings): appends with alignment from offset 0."""

    __slots__ = ('buf',)

    def __init__(self) -> None:
        self.buf = bytearray(ENCAPSULATION)

    def align(self, size: int) -> None:
        pad = -(len(self.buf) - 4) % size
        if pad:
            self.buf += b'\x00' * pad

    def pack(self, code: str, size: int, *values) -> None:
        self.align(size)
        self.buf += struct.pack('<' + code, *values)

    def string(self, text: str) -> None:
        self.align(4)
        self.buf += _string(text)

    def header(self, ns: int, frame: str) -> None:
        self.pack('iI', 4, ns // 1_000_000_000, ns % 1_000_000_000)
        self.string(frame)

    def float64_sequence(self, values: np.ndarray) -> None:
        self.pack('I', 4, len(values))
        if len(values):
            self.align(8)
            self.buf += np.ascontiguousarray(values, dtype='<f8').tobytes()

    def string_sequence(self, texts: Sequence[str]) -> None:
        self.pack('I', 4, len(texts))
        for text in texts:
            self.string(text)

    def value(self) -> bytes:
        return bytes(self.buf)


class TopicEncoder:
    """
    CDR bytes of every topic the offline runner records, for fixed frame ids.

    The frame ids default to the interface's (sim_node's defaults). Each method returns
    (topic, type name, CDR bytes) tuples in the order sim_node publishes them.
    """

    def __init__(
        self,
        frame_id: str = FRAME_ID,
        odom_frame_id: str = ODOM_FRAME_ID,
        base_frame_id: str = BASE_FRAME_ID,
    ) -> None:
        self.frame_id = frame_id
        frame = _string(frame_id)
        self._float64 = struct.Struct('<d')
        # geometry_msgs/TwistStamped and WrenchStamped: header + 6 float64 (linear/force x first)
        vec = _Layout()
        vec.header(frame)
        vec.add('d', 8, 6)
        self._vector6 = vec.to_struct()
        self._frame = frame
        # nav_msgs/Odometry: header, child_frame_id, pose (position, orientation, 36 covariance),
        # twist (linear, angular, 36 covariance); only x, orientation.w and linear.x vary/are set
        odom = _Layout()
        odom.header(_string(odom_frame_id))
        self._odom_frame = _string(odom_frame_id)
        self._base_frame = _string(base_frame_id)
        odom.raw(self._base_frame)
        odom.add('d', 8, 7 + 36 + 6 + 36)
        self._odometry = odom.to_struct()
        self._odometry_zeros = (0.0,) * 36
        self._clock = struct.Struct('<iI')
        self._types = dict(TOPIC_TYPES)
        self._ledger_head: bytes | None = None  # the ledger up to its status' level, stamp 0
        self._ledger_keys: dict[tuple, list[str]] = {}  # ledger keys -> padded strings

    def type_of(self, topic: str) -> str:
        """Return the ROS type name of a pulsejet topic (interface.TOPIC_TYPES)."""
        return self._types[topic]

    # -- messages -------------------------------------------------------------------------------
    def float64(self, value: float) -> bytes:
        """Return a std_msgs/Float64."""
        return ENCAPSULATION + self._float64.pack(float(value))

    def observation(self, obs: Observation, ns: int) -> list[tuple[str, bytes]]:
        """Return every state topic's bytes for one observation, stamped ns (as sim_node's)."""
        sec, nsec = divmod(ns, 1_000_000_000)
        frame = self._frame
        pack6 = self._vector6.pack
        position = float(obs.position_m)
        velocity = float(obs.velocity_m_s)
        zeros = self._odometry_zeros
        return [
            (TOPIC_MANTLE_RADIUS, ENCAPSULATION + self._float64.pack(float(obs.mantle_radius_m))),
            (TOPIC_VOLUME, ENCAPSULATION + self._float64.pack(float(obs.volume_m3))),
            (
                TOPIC_VELOCITY,
                ENCAPSULATION + pack6(sec, nsec, frame, velocity, 0.0, 0.0, 0.0, 0.0, 0.0),
            ),
            (
                TOPIC_THRUST,
                ENCAPSULATION
                + pack6(sec, nsec, frame, float(obs.thrust_n), 0.0, 0.0, 0.0, 0.0, 0.0),
            ),
            (TOPIC_FLUID_MASS, ENCAPSULATION + self._float64.pack(float(obs.fluid_mass_kg))),
            (
                TOPIC_ODOMETRY,
                ENCAPSULATION
                + self._odometry.pack(
                    sec, nsec, self._odom_frame, self._base_frame,
                    position, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, *zeros,
                    velocity, 0.0, 0.0, 0.0, 0.0, 0.0, *zeros,
                ),
            ),
            (TOPIC_CLOCK, ENCAPSULATION + self._clock.pack(sec, nsec)),
        ]

    def commands(self, cmd: Command) -> list[tuple[str, bytes]]:
        """Return the Float64 message of each actuator (as messages.command_messages does)."""
        return [
            (topic, ENCAPSULATION + self._float64.pack(float(getattr(cmd, COMMAND_FIELDS[topic]))))
            for topic in COMMAND_TOPICS
        ]

    def joint_state(self, names: Sequence[str], positions: Iterable[float], ns: int) -> bytes:
        """Return a sensor_msgs/JointState, velocity and effort filled with zeros (as sim_node)."""
        values = np.array([float(v) for v in positions], dtype='<f8')
        w = _Writer()
        w.header(ns, self.frame_id)
        w.string_sequence(names)
        w.float64_sequence(values)
        zeros = np.zeros(len(values))
        w.float64_sequence(zeros)
        w.float64_sequence(zeros)
        return w.value()

    def applied_command(self, cmd: Command, ns: int) -> bytes:
        """Return the command held from ns on (as messages.applied_command_message)."""
        return self.joint_state(
            APPLIED_COMMAND_NAMES, (getattr(cmd, n) for n in APPLIED_COMMAND_NAMES), ns
        )

    def profile(self, r_m, z_m, ns: int) -> bytes:
        """
        Return the mantle meridian as geometry_msgs/PolygonStamped (messages.profile_message).

        Point32 x = axial position z_m, y = radius r_m, z = 0 (float32, rounded to nearest).
        """
        r = np.asarray(r_m, dtype=np.float64)
        z = np.asarray(z_m, dtype=np.float64)
        if r.shape != z.shape or r.ndim != 1:
            raise ValueError(
                f'profile with {r.shape} radii and {z.shape} axial positions; allowed: two 1-D '
                'arrays of the same length'
            )
        points = np.zeros((len(r), 3), dtype='<f4')
        points[:, 0] = z
        points[:, 1] = r
        sec, nsec = divmod(ns, 1_000_000_000)
        # header (12 + frame) then the uint32 count; Point32's float32 need only 4-alignment
        head = struct.pack('<iI', sec, nsec) + self._frame
        head += b'\x00' * (-len(head) % 4)
        return ENCAPSULATION + head + struct.pack('<I', len(r)) + points.tobytes()

    def ledger(self, ledger: Mapping[str, float], ns: int) -> bytes:
        """Return the energy ledger as a diagnostic_msgs/DiagnosticArray (ledger_message)."""
        level, message = ledger_status(ledger)
        head = self._ledger_head
        if head is None:
            w = _Writer()
            w.header(0, self.frame_id)
            w.pack('I', 4, 1)  # one DiagnosticStatus
            head = self._ledger_head = bytes(w.buf)
        buf = bytearray(head)
        _STAMP.pack_into(buf, 4, ns // 1_000_000_000, ns % 1_000_000_000)
        buf.append(level)
        # every string 4-aligned from the body start, 4 bytes in: len(buf) % 4 is that offset
        buf += _PADS[-len(buf) % 4]
        buf += _LEDGER_NAME
        data = message.encode('utf-8')
        buf += _PADS[-len(buf) % 4]
        buf += _UINT32.pack(len(data) + 1)
        buf += data
        buf += b'\x00'
        buf += _PADS[-len(buf) % 4]
        buf += _LEDGER_HARDWARE_ID
        buf += _PADS[-len(buf) % 4]
        buf += _UINT32.pack(len(ledger))
        if not ledger:
            return bytes(buf)
        # the KeyValues as latin-1 text, one str operation each (the ledger is the only long
        # message built per sample): every CDR string starts 4-aligned, so a key or a value is
        # its CDR string padded to 4 bytes whatever came before; the last value is not padded
        keys = self._ledger_keys.get(tuple(ledger))
        if keys is None:
            keys = self._ledger_keys[tuple(ledger)] = [_padded_string(k) for k in ledger]
        # the repr of a list of floats is its items' repr(float) joined by ', ': one call
        values = repr(list(map(float, ledger.values())))[1:-1].split(', ')
        frames = _VALUE_FRAMES
        text = ''.join([key + frames[len(value)] % value for key, value in zip(keys, values)])
        return bytes(buf) + text.encode('latin-1')[:len(text) - (-(5 + len(values[-1])) % 4)]


def _padded_string(text: str) -> str:
    """Return a CDR string (uint32 length with the NUL, UTF-8, NUL) padded to 4, as latin-1."""
    data = _string(str(text))
    return (data + _PADS[-len(data) % 4]).decode('latin-1')


# a value's text of n characters (n < 64; a float's repr has at most 24) -> '%s' framed as a
# padded CDR string, as latin-1: its uint32 length, the text, the NUL and the padding to 4 bytes
# (a '%' byte of the length escaped)
_VALUE_FRAMES = [
    (_UINT32.pack(n + 1).decode('latin-1').replace('%', '%%') + '%s'
     + '\x00' * (1 + (-(5 + n) % 4)))
    for n in range(64)
]


class ColumnEncoder:
    """
    CDR bytes of many messages of one topic at once, from columns of values (numpy arrays).

    Each method returns an (n, size) uint8 array: row i is the message TopicEncoder writes for
    the i-th values, byte for byte (test_recording compares them). Every message of a topic here
    has one size (fixed frame ids, names and point counts), so a row is a copy of one template
    message with the varying fields written over it: no Python object per message, which is what
    lets an offline run record at nearly the speed of its physics.
    """

    def __init__(self, encoder: TopicEncoder | None = None) -> None:
        self.encoder = encoder or TopicEncoder()
        enc = self.encoder
        self._vector6 = ENCAPSULATION + enc._vector6.pack(0, 0, enc._frame, *(0.0,) * 6)
        zeros = enc._odometry_zeros
        self._odometry = ENCAPSULATION + enc._odometry.pack(
            0, 0, enc._odom_frame, enc._base_frame,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, *zeros, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *zeros,
        )
        # the varying doubles: vector x first (the message's last six doubles); odometry's pose
        # position x first of its 7 + 36 + 6 + 36 doubles, twist linear x after pose and covariance
        self._vector6_x = len(self._vector6) - 6 * 8
        self._odometry_x = len(self._odometry) - 85 * 8
        self._odometry_vx = self._odometry_x + 43 * 8
        names = APPLIED_COMMAND_NAMES
        self._joint_state = enc.joint_state(names, (0.0,) * len(names), 0)
        # positions follow the header, the names and the count, 8-aligned (as _Writer lays out)
        w = _Writer()
        w.header(0, enc.frame_id)
        w.string_sequence(names)
        w.pack('I', 4, len(names))
        w.align(8)
        self._joint_state_positions = len(w.buf)

    def float64(self, values: np.ndarray) -> np.ndarray:
        """Return std_msgs/Float64 rows."""
        rows = _rows(ENCAPSULATION + b'\x00' * 8, len(values))
        _put(rows, 4, '<f8', values)
        return rows

    def state(
        self, ns: np.ndarray, values: Mapping[str, np.ndarray]
    ) -> list[tuple[str, np.ndarray]]:
        """
        Return every state topic's rows, in the order of TopicEncoder.observation.

        values: arrays named like Observation's fields (mantle_radius_m, volume_m3, velocity_m_s,
        thrust_n, fluid_mass_kg, position_m), one entry per message; ns: their stamps.
        """
        velocity = _stamped(self._vector6, ns)
        _put(velocity, self._vector6_x, '<f8', values['velocity_m_s'])
        thrust = _stamped(self._vector6, ns)
        _put(thrust, self._vector6_x, '<f8', values['thrust_n'])
        odometry = _stamped(self._odometry, ns)
        _put(odometry, self._odometry_x, '<f8', values['position_m'])
        _put(odometry, self._odometry_vx, '<f8', values['velocity_m_s'])
        clock = _stamped(ENCAPSULATION + b'\x00' * 8, ns)
        return [
            (TOPIC_MANTLE_RADIUS, self.float64(values['mantle_radius_m'])),
            (TOPIC_VOLUME, self.float64(values['volume_m3'])),
            (TOPIC_VELOCITY, velocity),
            (TOPIC_THRUST, thrust),
            (TOPIC_FLUID_MASS, self.float64(values['fluid_mass_kg'])),
            (TOPIC_ODOMETRY, odometry),
            (TOPIC_CLOCK, clock),
        ]

    def commands(self, values: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """
        Return each actuator topic's Float64 rows (TopicEncoder.commands).

        values: (n, len(APPLIED_COMMAND_NAMES)) command values, columns in that order.
        """
        column = {name: i for i, name in enumerate(APPLIED_COMMAND_NAMES)}
        return [
            (topic, self.float64(values[:, column[COMMAND_FIELDS[topic]]]))
            for topic in COMMAND_TOPICS
        ]

    def applied_commands(self, ns: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Return sensor_msgs/JointState rows of held commands (TopicEncoder.applied_command)."""
        rows = _stamped(self._joint_state, ns)
        _put(rows, self._joint_state_positions, '<f8', values)
        return rows

    def profiles(self, ns: np.ndarray, r_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
        """
        Return geometry_msgs/PolygonStamped rows of meridians (TopicEncoder.profile).

        r_m, z_m: (n, points) node radii and axial positions, one meridian per row.
        """
        r = np.asarray(r_m, dtype=np.float64)
        z = np.asarray(z_m, dtype=np.float64)
        if r.shape != z.shape or r.ndim != 2 or len(r) != len(ns):
            raise ValueError(
                f'profiles with {r.shape} radii, {z.shape} axial positions and {len(ns)} stamps; '
                'allowed: two (n, points) arrays and n stamps'
            )
        points = np.zeros(r.shape + (3,), dtype='<f4')
        points[:, :, 0] = z
        points[:, :, 1] = r
        template = self.encoder.profile(r[0], z[0], 0) if len(r) else b''
        rows = _stamped(template, ns)
        if len(r):
            rows[:, len(template) - points[0].nbytes:] = points.reshape(len(r), -1).view(np.uint8)
        return rows


def _rows(template: bytes, n: int) -> np.ndarray:
    """Return n copies of one message as an (n, size) uint8 array."""
    rows = np.empty((n, len(template)), dtype=np.uint8)
    rows[:] = np.frombuffer(template, dtype=np.uint8)
    return rows


def _put(rows: np.ndarray, offset: int, dtype: str, values) -> None:
    """Write one value (or one row of values) per message at byte offset, little endian."""
    if not len(rows):
        return
    column = np.ascontiguousarray(values, dtype=dtype).reshape(len(rows), -1).view(np.uint8)
    rows[:, offset:offset + column.shape[1]] = column


def _stamped(template: bytes, ns: np.ndarray) -> np.ndarray:
    """Return copies of a message whose Header (or Clock) stamp follows the encapsulation, set."""
    ns = np.asarray(ns, dtype=np.int64)
    rows = _rows(template, len(ns))
    _put(rows, 4, '<i4', ns // 1_000_000_000)
    _put(rows, 8, '<u4', ns % 1_000_000_000)
    return rows


def stamps_ns(times_s: np.ndarray) -> np.ndarray:
    """Return stamp_ns of each time (the same rounding), as int64; ValueError names a bad one."""
    t = np.asarray(times_s, dtype=np.float64)
    # min and max: a NaN makes both comparisons false (the element-wise check finds it)
    if t.size and not (t.min() >= 0.0 and t.max() < _MAX_STAMP_S):
        bad = ~(np.isfinite(t) & (t >= 0.0) & (t < _MAX_STAMP_S))
        stamp_ns(float(t[np.flatnonzero(bad)[0]]))  # raises with the value
    # Python's round() of a float and np.rint both round half to even, on the same product
    return np.rint(t * 1e9).astype(np.int64)


def ledger_status(ledger: Mapping[str, float]) -> tuple[int, str]:
    """
    Return the (DiagnosticStatus level, message) of an energy ledger in J.

    OK, or WARN when |closure_relative| > LEDGER_WARN_RELATIVE (or is not finite): the books do not
    balance; or WARN when they balance only because the model's equations create energy (the
    `created_*` keys) of more than LEDGER_WARN_RELATIVE of the energy put in. The same rule and
    text as messages.ledger_message.
    """
    closure = float(ledger.get('closure_relative', 0.0))
    created = sum(float(v) for k, v in ledger.items() if str(k).startswith('created_'))
    energy_in = float(ledger.get('in_initial', 0.0)) + abs(
        float(ledger.get('in_actuation_work', 0.0))
    )
    created_relative = created / max(energy_in, 1e-12)
    if not (math.isfinite(closure) and abs(closure) <= LEDGER_WARN_RELATIVE):
        return LEVEL_WARN, f'energy closure {closure:+.2%} exceeds {LEDGER_WARN_RELATIVE:.0%}'
    if abs(created_relative) > LEDGER_WARN_RELATIVE:
        return LEVEL_WARN, (
            f'energy closure {closure:+.2%}, but the equations create {created:+.4g} J '
            f'({created_relative:+.0%} of the energy put in; created_* keys)'
        )
    return LEVEL_OK, f'energy closure {closure:+.2%} (within {LEDGER_WARN_RELATIVE:.0%})'


#: the topics TopicEncoder writes (the offline runner's recording)
RECORDED_TOPICS = (
    *STATE_TOPICS,
    *COMMAND_TOPICS,
    TOPIC_APPLIED_COMMAND,
    TOPIC_MANTLE_PROFILE,
    TOPIC_ENERGY_LEDGER,
)
