"""
sim_node's output as a client sees it: states assembled on /clock, applied commands, diagnostics.

`StateListener` subscribes a client node to the state topics and keeps the latest value of each;
sim_node publishes /clock last in each batch, so a `SimState` is built when a /clock sample arrives
from the latest values of the others. It also keeps the commands sim_node applied (its
applied-command topic) and sim_node's /diagnostics statuses, each with the wall time it arrived.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from typing import Any, Callable

from pulsejet_sim.core import topics as names


@dataclasses.dataclass(frozen=True)
class SimState:
    """One published state of the simulator (SI units), built when its /clock sample arrives."""

    time_s: float
    velocity_m_s: float
    volume_m3: float
    mantle_radius_m: float
    thrust_n: float
    fluid_mass_kg: float
    wall_s: float  # time.monotonic() when it was received


@dataclasses.dataclass(frozen=True)
class Diagnostic:
    level: int  # diagnostic_msgs/DiagnosticStatus OK=0, WARN=1, ERROR=2
    message: str
    values: dict
    time_s: float
    wall_s: float


def stamp_s(stamp) -> float:
    """Return a builtin_interfaces/Time as seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


class StateListener:
    """The state, applied-command and /diagnostics subscriptions of one client node."""

    def __init__(self, node, qos, history: int = 100_000):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TwistStamped, WrenchStamped
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        self.states: collections.deque[SimState] = collections.deque(maxlen=history)
        self.diagnostics: collections.deque[Diagnostic] = collections.deque(maxlen=1000)
        self.applied: collections.deque[tuple[float, Any, float]] = collections.deque(
            maxlen=history
        )
        self.received = 0  # states received in total (the deque keeps the last `history`)
        self._values: dict[str, float] = {}
        for topic in (names.TOPIC_VOLUME, names.TOPIC_MANTLE_RADIUS, names.TOPIC_FLUID_MASS):
            node.create_subscription(Float64, topic, self._store_value(topic), qos)
        node.create_subscription(
            TwistStamped,
            names.TOPIC_VELOCITY,
            lambda m: self._values.__setitem__('velocity', m.twist.linear.x),
            qos,
        )
        node.create_subscription(
            WrenchStamped,
            names.TOPIC_THRUST,
            lambda m: self._values.__setitem__('thrust', m.wrench.force.x),
            qos,
        )
        node.create_subscription(Clock, names.TOPIC_CLOCK, self._on_clock, qos)
        node.create_subscription(JointState, names.TOPIC_APPLIED_COMMAND, self._on_applied, qos)
        node.create_subscription(
            DiagnosticArray, names.TOPIC_DIAGNOSTICS, self._on_diagnostics, qos
        )

    @property
    def latest(self) -> SimState | None:
        return self.states[-1] if self.states else None

    def first_match(
        self, predicate: Callable[[SimState], bool], start: int, since_wall: float | None = None
    ) -> tuple[SimState | None, int]:
        """
        Return the first state from stream index `start` on with predicate(state) true.

        States received before time.monotonic() `since_wall` are skipped. Returns (the state or
        None, the index to start the next search from).
        """
        states, total = self.states, self.received
        offset = total - len(states)  # stream index of states[0]
        for i in range(max(start, offset), total):
            s = states[i - offset]
            if (since_wall is None or s.wall_s >= since_wall) and predicate(s):
                return s, i
        return None, total

    def _store_value(self, topic):
        key = topic.rsplit('/', 1)[1]

        def cb(msg):
            self._values[key] = msg.data

        return cb

    def _on_clock(self, msg):
        v = self._values
        self.received += 1
        self.states.append(
            SimState(
                time_s=stamp_s(msg.clock),
                velocity_m_s=v.get('velocity', math.nan),
                volume_m3=v.get('volume', math.nan),
                mantle_radius_m=v.get('mantle_radius', math.nan),
                thrust_n=v.get('thrust', math.nan),
                fluid_mass_kg=v.get('fluid_mass', math.nan),
                wall_s=time.monotonic(),
            )
        )

    def _on_applied(self, msg):
        from pulsejet_sim.ros.messages import command_from_applied

        t, cmd = command_from_applied(msg)
        self.applied.append((t, cmd, time.monotonic()))

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith('pulsejet: ') and status.name.endswith('sim_node'):
                self.diagnostics.append(
                    Diagnostic(
                        level=(
                            int.from_bytes(status.level, 'little')
                            if isinstance(status.level, bytes)
                            else int(status.level)
                        ),
                        message=status.message,
                        values={kv.key: kv.value for kv in status.values},
                        time_s=stamp_s(msg.header.stamp),
                        wall_s=time.monotonic(),
                    )
                )
