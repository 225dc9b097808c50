"""
Simulation values -> ROS 2 messages, one function per kind of data.

sim_node (live) and the offline runner both build their messages here, so live and offline
recordings carry the same topics, types, frames and stamps. Topic names are relative (the node
namespace applies), except `/clock`. Every header is stamped with simulation time.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Point32, PolygonStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.core.topics import (  # noqa: F401  (re-exported: the names of every message)
    APPLIED_COMMAND_NAMES,
    BASE_FRAME_ID,
    COMMAND_FIELDS,
    COMMAND_TOPICS,
    FRAME_ID,
    LATCHED_TOPICS,
    LEDGER_HARDWARE_ID,
    LEDGER_STATUS_NAME,
    LEDGER_WARN_RELATIVE,
    MANTLE_MARKER_SEGMENTS,
    ODOM_FRAME_ID,
    SERVICE_PAUSE,
    SERVICE_RESET,
    SERVICE_STEP,
    STATE_TOPICS,
    TOPIC_APPLIED_COMMAND,
    TOPIC_CLOCK,
    TOPIC_CMD_CABLE_FORCE,
    TOPIC_CMD_COMMAND,
    TOPIC_CMD_PUMP_FLOW,
    TOPIC_CMD_VALVE,
    TOPIC_DIAGNOSTICS,
    TOPIC_ENERGY_LEDGER,
    TOPIC_FLUID_MASS,
    TOPIC_MANTLE_MARKER,
    TOPIC_MANTLE_PROFILE,
    TOPIC_MANTLE_RADIUS,
    TOPIC_ODOMETRY,
    TOPIC_THRUST,
    TOPIC_TYPES,
    TOPIC_VELOCITY,
    TOPIC_VOLUME,
)
from pulsejet_sim.view.mesh import mantle_vertices  # noqa: F401  (re-exported)
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from visualization_msgs.msg import Marker


def message_class(topic: str) -> type:
    """Return the rclpy message class of a TOPIC_TYPES topic; ValueError names an unknown one."""
    classes = {
        'std_msgs/msg/Float64': Float64,
        'geometry_msgs/msg/TwistStamped': TwistStamped,
        'geometry_msgs/msg/WrenchStamped': WrenchStamped,
        'rosgraph_msgs/msg/Clock': Clock,
        'diagnostic_msgs/msg/DiagnosticArray': DiagnosticArray,
        'sensor_msgs/msg/JointState': JointState,
        'nav_msgs/msg/Odometry': Odometry,
        'geometry_msgs/msg/PolygonStamped': PolygonStamped,
    }
    try:
        return classes[TOPIC_TYPES[topic]]
    except KeyError:
        raise ValueError(
            f'topic {topic!r} is not a pulsejet topic; allowed: {sorted(TOPIC_TYPES)}'
        ) from None


def reliable_qos(topic: str, depth: int) -> QoSProfile:
    """
    Return the reliable QoS of `topic` (relative or resolved name) at `depth`.

    Transient local for interface.LATCHED_TOPICS, volatile otherwise; publishers and subscribers
    of a latched topic must both use it (a transient-local subscription ignores volatile writers).
    """
    latched = any(topic == name or topic.endswith('/' + name) for name in LATCHED_TOPICS)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def stamp(time_s: float) -> Time:
    """Convert simulation time in s to builtin_interfaces/Time (nanosecond resolution, rounded)."""
    t = float(time_s)
    if not math.isfinite(t) or t < 0.0 or t >= 2.0**31:
        raise ValueError(f'time_s={time_s!r} rejected; allowed: a finite time in [0, 2^31) s')
    total_ns = round(t * 1e9)
    return Time(sec=total_ns // 1_000_000_000, nanosec=total_ns % 1_000_000_000)


def stamp_ns(time_s: float) -> int:
    """Convert simulation time in s to integer ns (the log time the offline runner should use)."""
    t = stamp(time_s)
    return t.sec * 1_000_000_000 + t.nanosec


def _float64(value: float) -> Float64:
    return Float64(data=float(value))


def odometry_message(
    obs: Observation, odom_frame_id: str = ODOM_FRAME_ID, base_frame_id: str = BASE_FRAME_ID
) -> Odometry:
    """
    Return the body's pose in the odom frame and its twist in the body frame (REP 105).

    Pose: x = distance swum along the axis, m; twist: linear.x = speed, m/s; stamped with
    simulation time.
    """
    msg = Odometry()
    msg.header.stamp = stamp(obs.time_s)
    msg.header.frame_id = odom_frame_id
    msg.child_frame_id = base_frame_id
    msg.pose.pose.position.x = float(obs.position_m)
    msg.pose.pose.orientation.w = 1.0
    msg.twist.twist.linear.x = float(obs.velocity_m_s)
    return msg


def observation_messages(
    obs: Observation,
    frame_id: str = FRAME_ID,
    odom_frame_id: str = ODOM_FRAME_ID,
    base_frame_id: str = BASE_FRAME_ID,
) -> list[tuple[str, Any]]:
    """
    (topic, message) for every state topic of one observation, stamped with obs.time_s.

    Velocity goes in TwistStamped twist.linear.x (m/s), thrust in WrenchStamped wrench.force.x (N),
    both along the swimming axis (body x, forward +).
    """
    time = stamp(obs.time_s)
    velocity = TwistStamped()
    velocity.header.stamp = time
    velocity.header.frame_id = frame_id
    velocity.twist.linear.x = float(obs.velocity_m_s)
    thrust = WrenchStamped()
    thrust.header.stamp = time
    thrust.header.frame_id = frame_id
    thrust.wrench.force.x = float(obs.thrust_n)
    return [
        (TOPIC_MANTLE_RADIUS, _float64(obs.mantle_radius_m)),
        (TOPIC_VOLUME, _float64(obs.volume_m3)),
        (TOPIC_VELOCITY, velocity),
        (TOPIC_THRUST, thrust),
        (TOPIC_FLUID_MASS, _float64(obs.fluid_mass_kg)),
        (TOPIC_ODOMETRY, odometry_message(obs, odom_frame_id, base_frame_id)),
        (TOPIC_CLOCK, Clock(clock=time)),
    ]


def ledger_message(
    ledger: Mapping[str, float], time_s: float, frame_id: str = FRAME_ID
) -> DiagnosticArray:
    """
    Energy ledger (J) -> DiagnosticArray with one status `pulsejet energy ledger`.

    One KeyValue per key, value = repr(float) so it parses back to the exact float. Level OK, or
    WARN when |closure_relative| > 5 % (or is not finite): the books do not balance; or WARN when
    the books balance only because the model's equations create energy (the `created_*` keys, e.g.
    the lumped model's `paper` coupling) of more than 5 % of the energy put in.
    """
    closure = float(ledger.get('closure_relative', 0.0))
    created = sum(float(v) for k, v in ledger.items() if str(k).startswith('created_'))
    energy_in = float(ledger.get('in_initial', 0.0)) + abs(
        float(ledger.get('in_actuation_work', 0.0))
    )
    created_relative = created / max(energy_in, 1e-12)
    status = DiagnosticStatus()
    status.name = LEDGER_STATUS_NAME
    status.hardware_id = LEDGER_HARDWARE_ID
    if not (math.isfinite(closure) and abs(closure) <= LEDGER_WARN_RELATIVE):
        status.level = DiagnosticStatus.WARN
        status.message = f'energy closure {closure:+.2%} exceeds {LEDGER_WARN_RELATIVE:.0%}'
    elif abs(created_relative) > LEDGER_WARN_RELATIVE:
        status.level = DiagnosticStatus.WARN
        status.message = (
            f'energy closure {closure:+.2%}, but the equations create {created:+.4g} J '
            f'({created_relative:+.0%} of the energy put in; created_* keys)'
        )
    else:
        status.level = DiagnosticStatus.OK
        status.message = f'energy closure {closure:+.2%} (within {LEDGER_WARN_RELATIVE:.0%})'
    status.values = [KeyValue(key=str(k), value=repr(float(v))) for k, v in ledger.items()]
    array = DiagnosticArray()
    array.header.stamp = stamp(time_s)
    array.header.frame_id = frame_id
    array.status = [status]
    return array


def health_message(
    level: str,
    name: str,
    hardware_id: str,
    message: str,
    values: Mapping[str, Any],
    time_s: float,
    frame_id: str = FRAME_ID,
) -> DiagnosticArray:
    """
    Return a node's health as a DiagnosticArray of one status (level 'OK', 'WARN' or 'ERROR').

    Floats as repr (they parse back exactly), 'n/a' where not finite; other values as str.
    """
    status = DiagnosticStatus(
        level={
            'OK': DiagnosticStatus.OK,
            'WARN': DiagnosticStatus.WARN,
            'ERROR': DiagnosticStatus.ERROR,
        }[level],
        name=name,
        message=message,
        hardware_id=hardware_id,
    )
    status.values = [
        KeyValue(
            key=k,
            value=(
                (repr(float(v)) if math.isfinite(v) else 'n/a') if isinstance(v, float) else str(v)
            ),
        )
        for k, v in values.items()
    ]
    array = DiagnosticArray()
    array.header.stamp = stamp(time_s)
    array.header.frame_id = frame_id
    array.status = [status]
    return array


def ledger_from_message(msg: Any) -> dict[str, float]:
    """Inverse of ledger_message (works on rclpy or decoded-from-bag messages): key -> J."""
    out: dict[str, float] = {}
    for status in msg.status:
        if status.name == LEDGER_STATUS_NAME:
            for kv in status.values:
                out[kv.key] = float(kv.value)
    return out


def command_messages(cmd: Command) -> list[tuple[str, Float64]]:
    """
    Return (topic, Float64) for each actuator command.

    Pump flow m^3/s, valve opening 0..1, cable force N.
    """
    return [
        (TOPIC_CMD_PUMP_FLOW, _float64(cmd.pump_flow_m3_s)),
        (TOPIC_CMD_VALVE, _float64(cmd.valve_opening)),
        (TOPIC_CMD_CABLE_FORCE, _float64(cmd.cable_force_n)),
    ]


def _actuator_message(
    cmd: Command, names: Sequence[str], time_s: float, frame_id: str
) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(time_s)
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position = [float(getattr(cmd, name)) for name in names]
    # Filled, not empty: rosbags (0.11) misreads the padding rclpy writes for empty trailing
    # float64 sequences.
    msg.velocity = [0.0] * len(names)
    msg.effort = [0.0] * len(names)
    return msg


def applied_command_message(cmd: Command, time_s: float, frame_id: str = FRAME_ID) -> JointState:
    """
    Return the command held from time_s (simulation time) on.

    A JointState with names APPLIED_COMMAND_NAMES and the values in `position` (m^3/s, 0..1, N).
    """
    return _actuator_message(cmd, APPLIED_COMMAND_NAMES, time_s, frame_id)


def command_message(
    cmd: Command,
    time_s: float,
    frame_id: str = FRAME_ID,
    fields: Sequence[str] = APPLIED_COMMAND_NAMES,
) -> JointState:
    """
    Return the atomic command (TOPIC_CMD_COMMAND) answering the state at time_s.

    It sets the actuators named in `fields` (default all of APPLIED_COMMAND_NAMES) at once; the
    others keep what they hold.
    """
    unknown = [f for f in fields if f not in APPLIED_COMMAND_NAMES]
    if unknown or not fields or len(set(fields)) != len(fields):
        raise ValueError(
            f'fields {list(fields)!r} rejected; allowed: distinct names from '
            f'{", ".join(APPLIED_COMMAND_NAMES)}, at least one'
        )
    return _actuator_message(cmd, fields, time_s, frame_id)


def command_values(msg: Any) -> tuple[float, dict[str, float]]:
    """
    Parse an atomic command message into (stamp in s, {field: value}).

    ValueError names what is wrong.
    """
    names, values = list(msg.name), list(msg.position)
    if len(names) != len(values) or not names:
        raise ValueError(
            f'{len(names)} names and {len(values)} positions; allowed: the same number, at least '
            f'one, names from {", ".join(APPLIED_COMMAND_NAMES)}'
        )
    unknown = [n for n in names if n not in APPLIED_COMMAND_NAMES]
    if unknown or len(set(names)) != len(names):
        raise ValueError(
            f'names {names!r}; allowed: distinct names from {", ".join(APPLIED_COMMAND_NAMES)}'
        )
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, dict(
        zip(names, (float(v) for v in values))
    )


def command_from_applied(msg: Any) -> tuple[float, Command]:
    """
    Return (time_s, Command) of an applied command message: inverse of applied_command_message.

    The message is an rclpy one or one decoded from a bag.
    """
    values = dict(zip(msg.name, msg.position))
    time_s = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    return time_s, Command(
        values['pump_flow_m3_s'], values['valve_opening'], values['cable_force_n']
    )


def profile_message(r_m, z_m, time_s: float, frame_id: str = FRAME_ID) -> PolygonStamped:
    """
    Return the mantle meridian as a PolygonStamped.

    Node radii r_m and axial positions z_m (m), in the body's x (axial, forward +) / y (radial)
    plane.
    """
    msg = PolygonStamped()
    msg.header.stamp = stamp(time_s)
    msg.header.frame_id = frame_id
    msg.polygon.points = [Point32(x=float(z), y=float(r), z=0.0) for r, z in zip(r_m, z_m)]
    return msg


def _mantle_marker_template(time_s: float, frame_id: str) -> Marker:
    msg = Marker()
    msg.header.stamp = stamp(time_s)
    msg.header.frame_id = frame_id
    msg.ns = 'pulsejet/mantle'
    msg.id = 0
    msg.type = Marker.TRIANGLE_LIST
    msg.action = Marker.ADD
    msg.pose.orientation.w = 1.0
    msg.scale.x = msg.scale.y = msg.scale.z = 1.0
    msg.color.r, msg.color.g, msg.color.b, msg.color.a = 0.95, 0.55, 0.35, 0.8
    return msg


def mantle_marker_cdr(
    r_m, z_m, time_s: float, frame_id: str = FRAME_ID, segments: int = MANTLE_MARKER_SEGMENTS
) -> bytes:
    """
    Return mantle_marker's message serialised (CDR), its points written from an array.

    What rclpy's publish(bytes) sends as is: the same bytes as serialising mantle_marker(...),
    without one Python object per vertex (14,400 for the shell robot, ~15 ms of the interpreter
    five times a second). The fields around `points` come from rclpy's own serialisation of the
    message without points; the points are a uint32 count, padding to 8 bytes and the float64
    triples (geometry_msgs/Point), as CDR lays out a sequence of structs of doubles.
    """
    from rclpy.serialization import serialize_message

    vertices = mantle_vertices(r_m, z_m, segments)
    msg = _mantle_marker_template(time_s, frame_id)
    msg.points = [Point(x=_SENTINEL_M)]
    one = serialize_message(msg)
    # find the one point by its value, its count just before it (CDR pads a sequence of doubles
    # to 8 bytes after the count); the rest of the message is rclpy's bytes unchanged (padding
    # bytes rclpy leaves unset are not compared by any reader)
    sentinel = np.float64(_SENTINEL_M).astype('<f8').tobytes()
    point = one.find(sentinel)
    count = np.uint32(1).astype('<u4').tobytes()
    at = next(
        (point - 4 - pad for pad in (0, 4) if one[point - 4 - pad:point - pad] == count), None
    )
    if one[:2] != b'\x00\x01' or point < 0 or at is None or one.find(sentinel, point + 1) >= 0:
        # not little-endian CDR, or the point not found once: let rclpy serialise it all
        msg.points = [Point(x=x, y=y, z=z) for x, y, z in vertices.tolist()]
        return serialize_message(msg)
    pad = (-at) % 8  # CDR aligns relative to the data after the 4-byte encapsulation header
    return b''.join(
        (
            one[:at],
            np.uint32(len(vertices)).astype('<u4').tobytes(),
            bytes(pad),
            np.ascontiguousarray(vertices, dtype='<f8').tobytes(),
            one[point + 24:],
        )
    )


#: an x no mantle has (m): marks where rclpy put the one point of mantle_marker_cdr's template
_SENTINEL_M = -1.2345678901234567e-300


def mantle_marker(
    r_m, z_m, time_s: float, frame_id: str = FRAME_ID, segments: int = MANTLE_MARKER_SEGMENTS
) -> Marker:
    """
    Return the mantle surface as a Marker TRIANGLE_LIST.

    The meridian (node radii r_m, axial positions z_m, m) revolved about the body's x axis in
    `segments` facets, two triangles per element and facet.
    """
    msg = _mantle_marker_template(time_s, frame_id)
    msg.points = [Point(x=x, y=y, z=z) for x, y, z in mantle_vertices(r_m, z_m, segments).tolist()]
    return msg
