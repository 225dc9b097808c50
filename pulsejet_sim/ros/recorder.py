r"""
ROS 2 node `recorder`: write subscribed topics to one MCAP file (rosbag2 layout) as they arrive.

Messages are taken raw (CDR bytes, no deserialization) and logged like `ros2 bag record` (Jazzy's
rosbag2_transport recorder): MCAP log_time is the middleware's receive time and publish_time its
source (send) time, both from the rmw message info (system clock, ns; the recorder's own clock when
the middleware gives none). A send time is when the publisher published, whatever the recorder's
executor was doing: gaps in it locate a stall in the publisher. The message info needs the
single-threaded executor (`PULSEJET_EXECUTOR=single`); with the default events executor, which
takes a 1 kHz topic for a third of the CPU (pulsejet_sim.ros.executor), both times are the
recorder's receive time. Analysis uses the simulation-time header stamps inside the messages.

    ros2 run pulsejet_sim recorder --ros-args -p output:=runs/x.mcap \
        -p topics:="['pulsejet/velocity']"

Parameters (read-only, with descriptors: `ros2 param describe /recorder output`): `output` (path;
default runs/<UTC date-time>.mcap), `topics` (string array; default every pulsejet topic incl.
commands, the energy ledger and /clock, plus /diagnostics and the mantle Marker; an entry may be
`name:pkg/msg/Type` for a topic outside the pulsejet set). On SIGINT/SIGTERM the messages already
delivered are written (none that DDS acknowledged is lost), the file is closed complete and its
path printed.
`Recorder(node, path, topics)` does the same inside another process's node.
"""

from __future__ import annotations

import datetime
import importlib
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Iterable, Sequence

from pulsejet_sim.bag import msgdefs
from pulsejet_sim.bag.writer import BagError, BagWriter, qos_profiles_yaml
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.executor import executor_kind, make_executor
from pulsejet_sim.ros.node_main import freeze_start_up_objects
from pulsejet_sim.ros.node_params import ParamSpec
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Deep, so a burst from a fast simulation is not dropped while the executor is busy.
QOS_DEPTH = 1000
# a topic is subscribed once its publishers are discovered, with the QoS they offer (rosbag2's
# rule): this often the recorder looks for publishers of the topics it has not subscribed yet
DISCOVERY_PERIOD_S = 0.1
STOP_POLL_S = 0.1  # a signal ends the recording within this time
DRAIN_IDLE_SPINS = 5  # at shutdown, taking stops after this many spins that wrote nothing
FLUSH_PERIOD_S = 1.0  # an idle recorder still pushes its last chunk to disk within this time
#: what the node records by default: every pulsejet topic and /clock, the nodes' health
#: (/diagnostics) and the mantle's 3-D view (a viewer of the recording shows it as it was live)
DEFAULT_TOPICS = tuple(messages.TOPIC_TYPES) + (
    f'{messages.TOPIC_DIAGNOSTICS}:diagnostic_msgs/msg/DiagnosticArray',
    f'{messages.TOPIC_MANTLE_MARKER}:visualization_msgs/msg/Marker',
)
# read-only: the file and its topics are fixed at start-up
PARAMETERS = (
    ParamSpec(
        'output',
        '',
        'MCAP file to write (rosbag2 layout); empty = runs/<UTC date-time>.mcap',
        read_only=True,
        allowed='a file path or empty',
    ),
    ParamSpec(
        'topics',
        DEFAULT_TOPICS,
        'topics to record: pulsejet topic names, or '
        '"name:pkg/msg/Type" for any other topic; default every pulsejet topic, /clock, '
        '/diagnostics and the mantle Marker',
        read_only=True,
        allowed='a list of topic names or "name:pkg/msg/Type" entries',
    ),
)


def default_output(now: datetime.datetime | None = None) -> Path:
    """runs/<YYYY-mm-dd_HH-MM-SS>.mcap (UTC) relative to the working directory."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    return Path('runs') / f'{now:%Y-%m-%d_%H-%M-%S}.mcap'


def parse_topics(entries: Iterable[str]) -> dict[str, str]:
    """
    Map topic entries to {topic: type name}.

    An entry is a pulsejet topic ('pulsejet/velocity', '/pulsejet/velocity', '/clock') or
    'name:pkg/msg/Type'. ValueError names a bad entry.
    """
    out: dict[str, str] = {}
    for entry in entries:
        if not isinstance(entry, str) or not entry.strip():
            raise ValueError(
                f'topic entry {entry!r} is empty; expected a topic name or "name:pkg/msg/Type"'
            )
        name, sep, type_name = entry.strip().partition(':')
        if sep:
            msgdefs.split_type_name(type_name)
        else:
            type_name = messages.TOPIC_TYPES.get(name) or messages.TOPIC_TYPES.get(
                name.lstrip('/'), ''
            )
            if not type_name:
                raise ValueError(
                    f'topic {name!r} is not a pulsejet topic and has no type; allowed: '
                    f'{sorted(messages.TOPIC_TYPES)} or "name:pkg/msg/Type"'
                )
        out[name] = type_name
    return out


def import_message_class(type_name: str) -> type:
    """
    Return the generated rclpy class of 'pkg/msg/Type'.

    ValueError names a type that is not installed.
    """
    package, namespace, name = msgdefs.split_type_name(type_name)
    try:
        return getattr(importlib.import_module(f'{package}.{namespace}'), name)
    except (ImportError, AttributeError):
        raise ValueError(
            f'message type {type_name!r} is not installed '
            f'(no class {name} in Python module {package}.{namespace})'
        ) from None


def subscription_qos(offered: Iterable[QoSProfile]) -> QoSProfile:
    """
    Return the QoS that records every publisher offering `offered` (rosbag2's rule).

    Reliable only when every publisher is reliable (a reliable subscription ignores best-effort
    publishers; a best-effort one loses samples under load, as /clock did), transient local only
    when every publisher is (a latched topic's history then reaches the recorder).
    """
    offered = list(offered)
    reliable = bool(offered) and all(
        q.reliability == ReliabilityPolicy.RELIABLE for q in offered
    )
    latched = bool(offered) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered
    )
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=QOS_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


class Recorder:
    """
    Subscribe raw to `topics` on `node` and write every message to `path` until close().

    topics: entries as for parse_topics; None = every topic in messages.TOPIC_TYPES. Topic names
    are resolved in the node's namespace and recorded fully qualified. As rosbag2 does, a topic is
    subscribed when its publishers are discovered, with the reliability and durability they all
    offer (`subscription_qos`), and appears in the file with its first message, carrying the QoS
    its publishers offered. The node's executor must spin (the discovery runs on a timer).
    """

    def __init__(
        self,
        node: Node,
        path: str | Path,
        topics: Sequence[str] | None = None,
        send_times: bool | None = None,
    ) -> None:
        self.node = node
        # rclpy 7.1.6's events executor cannot pass the message info (it raises SystemError): with
        # it, publish_time is the receive time too (default: send times with the single-threaded
        # executor only)
        self.send_times = (executor_kind() == 'single') if send_times is None else send_times
        wanted = parse_topics(topics if topics is not None else list(messages.TOPIC_TYPES))
        self.writer = BagWriter(path, flush_period_s=FLUSH_PERIOD_S)
        self.path = self.writer.path
        self._wanted = {
            node.resolve_topic_name(name): (import_message_class(type_name), type_name)
            for name, type_name in wanted.items()
        }
        self._subscriptions: dict[str, object] = {}
        self.subscribe_discovered()
        self._timers = [
            node.create_timer(FLUSH_PERIOD_S, self.writer.flush_if_due),
            node.create_timer(DISCOVERY_PERIOD_S, self.subscribe_discovered),
        ]

    @property
    def subscriptions(self) -> dict[str, object]:
        """Return the subscriptions made so far, by resolved topic name."""
        return dict(self._subscriptions)

    def subscribe_discovered(self) -> None:
        """Subscribe the wanted topics whose publishers are known by now."""
        if self.writer.closed:
            return
        for topic, (cls, type_name) in self._wanted.items():
            if topic in self._subscriptions:
                continue
            offered = [i.qos_profile for i in self.node.get_publishers_info_by_topic(topic)]
            if offered:
                self._subscriptions[topic] = self.node.create_subscription(
                    cls,
                    topic,
                    self._make_callback(topic, type_name),
                    subscription_qos(offered),
                    raw=True,
                )

    def _make_callback(self, topic: str, type_name: str):
        def write(data: bytes, receive_ns: int, send_ns: int) -> None:
            try:
                if topic not in self.writer.topics:
                    infos = self.node.get_publishers_info_by_topic(topic)
                    self.writer.add_topic(
                        topic, type_name, qos_profiles_yaml(i.qos_profile for i in infos)
                    )
                self.writer.write(topic, data, receive_ns, send_ns)
            except BagError:
                if not self.writer.closed:
                    raise
                # else: delivered by an executor thread while close() ran; recording has ended

        if not self.send_times:

            def on_message(data: bytes) -> None:
                now_ns = time.time_ns()
                write(data, now_ns, now_ns)

            return on_message

        def on_message_with_info(data: bytes, info: dict) -> None:
            receive_ns = info.get('received_timestamp') or time.time_ns()
            write(data, receive_ns, info.get('source_timestamp') or receive_ns)

        return on_message_with_info

    @property
    def message_counts(self) -> dict[str, int]:
        return self.writer.message_counts

    def drain(self, executor) -> None:
        """Write the messages already delivered to the subscriptions (spins `executor`)."""
        idle_spins = 0
        # a spin runs one callback; the flush timer's may be one that writes nothing
        while idle_spins < DRAIN_IDLE_SPINS:
            before = self.writer.message_count
            executor.spin_once(timeout_sec=0.0)
            idle_spins = idle_spins + 1 if self.writer.message_count == before else 0

    def close(self) -> Path:
        """Stop recording and close the file (idempotent); returns its path."""
        for timer in self._timers:
            self.node.destroy_timer(timer)
        self._timers.clear()
        for sub in self._subscriptions.values():
            self.node.destroy_subscription(sub)
        self._subscriptions.clear()
        self.writer.close()
        return self.path


def main(args: list[str] | None = None) -> int:
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    # rclpy's own handlers would shut the context down, and with it the messages delivered but
    # not yet taken; here a signal only ends the spinning
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = Node('recorder')
    values = {
        spec.name: node.declare_parameter(
            spec.name,
            list(spec.default) if isinstance(spec.default, tuple) else spec.default,
            spec.descriptor(),
        ).value
        for spec in PARAMETERS
    }
    output = values['output'] or str(default_output())
    topics = list(values['topics'] or DEFAULT_TOPICS)
    try:
        recorder = Recorder(node, output, topics)
    except (ValueError, OSError) as exc:
        print(f'recorder: error: {exc}', file=sys.stderr)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2
    print(f'recorder: writing {recorder.path} ({len(topics)} topics)', flush=True)
    freeze_start_up_objects()
    executor = make_executor()
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=STOP_POLL_S)
        if rclpy.ok():
            recorder.drain(executor)
    finally:
        path = recorder.close()
        counts = recorder.message_counts
        node.destroy_node()
        rclpy.try_shutdown()
        print(f'recorder: wrote {sum(counts.values())} messages to {path}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
