"""
What the live reliability runs (live_fuzz.py, soak.py) share.

Node processes in an isolated ROS domain, an in-process rclpy node that checks every published
state for non-finite values, the processes' resident memory, and a prober that times the parameter
services the way `ros2 param dump` uses them (list_parameters, then get_parameters of every name).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import time

from pulsejet_sim.core import topics
from pulsejet_sim.ros.launching import default_domain_id, NodeProcess


def node_env(domain: int) -> dict:
    """Return the children's environment: domain, localhost discovery, unbuffered plain logs."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # this process's participant too
    return dict(
        os.environ,
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
        RCUTILS_LOGGING_BUFFERED_STREAM='0',
        RCUTILS_COLORIZED_OUTPUT='0',
        PYTHONUNBUFFERED='1',
    )


def rss_bytes(pid: int) -> float:
    """Resident set size of a process (Linux /proc), NaN once it is gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float('nan')


def cpu_seconds(pid: int) -> float:
    """Return user + system CPU seconds of a process (Linux /proc), NaN once it is gone."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return float('nan')


def percentile(values, q: float) -> float:
    import numpy as np

    return float(np.percentile(values, q)) if len(values) else float('nan')


@dataclass
class StateWatch:
    """Counts the published states and every non-finite number in them."""

    messages: int = 0
    non_finite: int = 0
    examples: list = field(default_factory=list)
    clock_wall: list = field(default_factory=list)  # (wall monotonic s, sim s) of each /clock
    diagnostics: list = field(default_factory=list)  # (wall s, level, message, values) of sim_node
    diagnostics_clock: list = field(default_factory=list)  # (wall monotonic s, stamp s) of those

    def check(self, topic: str, numbers) -> None:
        self.messages += 1
        bad = [x for x in numbers if not math.isfinite(x)]
        if bad:
            self.non_finite += 1
            if len(self.examples) < 5:
                self.examples.append(f'{topic}: {bad[:3]}')


class LiveClient:
    """
    An rclpy context + node in the test domain.

    Subscribed to every state topic (unless state_topics is false), /clock (unless clock is
    false) and /diagnostics.
    """

    def __init__(
        self,
        domain: int,
        name: str,
        keep_clock: bool = False,
        state_topics: bool = True,
        clock: bool = True,
    ):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TwistStamped, WrenchStamped
        from nav_msgs.msg import Odometry
        from pulsejet_sim.ros.executor import make_executor
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Float64

        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=domain,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = make_executor(context=self.context)
        self.executor.add_node(self.node)
        self.watch = StateWatch()
        self.keep_clock = keep_clock
        self.last_clock_s = None
        w = self.watch
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.qos = qos
        if state_topics:  # (a soak at 1 kHz leaves them out: this process would not keep up)
            for topic in (
                topics.TOPIC_MANTLE_RADIUS,
                topics.TOPIC_VOLUME,
                topics.TOPIC_FLUID_MASS,
            ):
                self.node.create_subscription(
                    Float64, topic, lambda m, t=topic: w.check(t, (m.data,)), qos
                )
            self.node.create_subscription(
                TwistStamped,
                topics.TOPIC_VELOCITY,
                lambda m: w.check(
                    'velocity', (m.twist.linear.x, m.twist.linear.y, m.twist.linear.z)
                ),
                qos,
            )
            self.node.create_subscription(
                WrenchStamped,
                topics.TOPIC_THRUST,
                lambda m: w.check(
                    'thrust', (m.wrench.force.x, m.wrench.force.y, m.wrench.force.z)
                ),
                qos,
            )
            self.node.create_subscription(
                Odometry,
                topics.TOPIC_ODOMETRY,
                lambda m: w.check(
                    'odom',
                    (m.pose.pose.position.x, m.pose.pose.orientation.w, m.twist.twist.linear.x),
                ),
                qos,
            )
        self.clock_subscribed = clock
        if clock:  # else simulated time comes from the 1 Hz /diagnostics stamps (light at 1 kHz)
            self.node.create_subscription(Clock, topics.TOPIC_CLOCK, self._on_clock, qos)
        self.node.create_subscription(
            DiagnosticArray, topics.TOPIC_DIAGNOSTICS, self._on_diagnostics, qos
        )

    def _on_clock(self, msg) -> None:
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        self.last_clock_s = t
        if self.keep_clock:
            self.watch.clock_wall.append((time.monotonic(), t))

    def _on_diagnostics(self, msg) -> None:
        for s in msg.status:
            if s.name.endswith('sim_node'):
                stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                self.watch.diagnostics_clock.append((time.monotonic(), stamp_s))
                if not self.clock_subscribed:
                    self.last_clock_s = stamp_s
                self.watch.diagnostics.append(
                    (
                        time.monotonic(),
                        (
                            int.from_bytes(s.level, 'little')
                            if isinstance(s.level, bytes)
                            else int(s.level)
                        ),
                        s.message,
                        {kv.key: kv.value for kv in s.values},
                    )
                )

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while True:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.01, end - time.monotonic())))
            if time.monotonic() >= end:
                return

    def spin_until(self, predicate, timeout_s: float, what: str, processes=()) -> None:
        end = time.monotonic() + timeout_s
        while not predicate():
            for p in processes:
                if not p.alive():
                    raise RuntimeError(
                        f'{p.module} exited with {p.proc.returncode} while waiting for {what}:\n'
                        f'{p.output()[-2000:]}'
                    )
            if time.monotonic() > end:
                raise RuntimeError(f'timed out after {timeout_s:g} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


class ParamProbe:
    """
    Time sim_node's parameter services as `ros2 param dump` uses them.

    First list_parameters, then get_parameters of every listed name; a round starts every
    `period_s` (as a user or a monitoring script would dump them, not back to back). A round that
    does not finish in `timeout_s` is a starved service; the prober waits for it (it never sends
    a second round on top of a pending one).
    """

    def __init__(
        self, node, target: str = '/sim_node', timeout_s: float = 10.0, period_s: float = 1.0
    ):
        from rcl_interfaces.srv import GetParameters, ListParameters

        self._list = node.create_client(ListParameters, f'{target}/list_parameters')
        self._get = node.create_client(GetParameters, f'{target}/get_parameters')
        self.timeout_s = timeout_s
        self.latencies_s: list[float] = []
        self.starved = 0
        self.period_s = period_s
        self._next_round = 0.0
        self._pending = None  # (future, started wall s, stage)

    def poll(self) -> None:
        """Advance the current round (call often); starts a new round when none is pending."""
        from rcl_interfaces.srv import GetParameters, ListParameters

        now = time.monotonic()
        p = self._pending
        if p is None:
            if now >= self._next_round and self._list.service_is_ready():
                self._next_round = now + self.period_s
                self._pending = {
                    'future': self._list.call_async(ListParameters.Request()),
                    'started': now,
                    'stage': 'list',
                    'starved': False,
                }
            return
        if p['future'].done():
            if p['stage'] == 'list':
                names = list(p['future'].result().result.names)
                p['future'], p['stage'] = (
                    self._get.call_async(GetParameters.Request(names=names)),
                    'get',
                )
            else:
                self.latencies_s.append(now - p['started'])
                self._pending = None
        elif now - p['started'] > self.timeout_s and not p['starved']:
            self.starved += 1
            p['starved'] = True

    def summary(self) -> dict:
        return {
            'rounds': len(self.latencies_s),
            'p50_ms': percentile(self.latencies_s, 50) * 1e3,
            'p99_ms': percentile(self.latencies_s, 99) * 1e3,
            'max_ms': max(self.latencies_s, default=float('nan')) * 1e3,
            'starved': self.starved,
        }


__all__ = [
    'LiveClient',
    'NodeProcess',
    'ParamProbe',
    'StateWatch',
    'cpu_seconds',
    'default_domain_id',
    'node_env',
    'percentile',
    'rss_bytes',
]
