"""
The recorder node as a real subprocess in an isolated DDS domain.

It is fed by a publisher node here.
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
import time

from pulsejet_sim.core.model_io import Command, Observation
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.launching import isolated_environment, pick_domain_id
from pulsejet_sim.ros.recorder import parse_topics, Recorder
import pytest
import rclpy
from rclpy.duration import Duration
import rclpy.executors
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rosbags.highlevel import AnyReader

REPO = Path(__file__).resolve().parents[1]
N_STEPS = 40


def domain_id(offset: int) -> int:
    """
    Return a ROS domain id, 1..100, different per test run (pid) and per test (offset).

    So parallel runs do not cross-talk (offsets 10-17 of pulsejet_sim.ros.launching's: no other
    test file takes them).
    """
    return pick_domain_id(10 + offset)


def observation(i: int) -> Observation:
    return Observation(
        time_s=0.02 * i,
        position_m=0.0,
        velocity_m_s=0.1 * i,
        acceleration_m_s2=0.0,
        mantle_radius_m=0.04 + 1e-3 * i,
        volume_m3=2e-4,
        fluid_mass_kg=0.2 + 0.01 * i,
        thrust_n=0.25 * i,
        added_mass_force_n=0.0,
        drag_n=0.0,
        jet_speed_m_s=0.0,
        cavity_pressure_pa=0.0,
        pump_flow_m3_s=0.0,
        valve_opening=1.0,
    )


def wait_acked(publisher) -> None:
    """Wait until the subscriptions acknowledged every sample (bounded by the test's timeout)."""
    while not publisher.wait_for_all_acked(Duration(seconds=1)):
        pass


class Publisher:
    """A node in its own context on `domain` publishing pulsejet topics built by messages.py."""

    def __init__(self, domain: int, topics: list[str]) -> None:
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO
        )
        self.node = Node('test_publisher', context=self.context)
        self.pubs = {
            t: self.node.create_publisher(
                messages.message_class(t), t, messages.reliable_qos(t, 1000)
            )
            for t in topics
        }

    def wait_matched(self, timeout_s: float = 15.0) -> None:
        deadline = time.monotonic() + timeout_s
        while any(p.get_subscription_count() == 0 for p in self.pubs.values()):
            assert time.monotonic() < deadline, 'recorder subscriptions never matched'
            time.sleep(0.05)

    def publish_run(self) -> None:
        for i in range(N_STEPS):
            obs = observation(i)
            batch = messages.observation_messages(obs) + messages.command_messages(
                Command(1e-3, 0.25 * (i % 4), 0.0)
            )
            batch.append(
                (
                    messages.TOPIC_ENERGY_LEDGER,
                    messages.ledger_message({'in_actuation_work': 0.5 * i}, obs.time_s),
                )
            )
            batch.append(
                (
                    messages.TOPIC_MANTLE_PROFILE,
                    messages.profile_message([0.0, 0.01 * (1 + i)], [0.05, -0.05], obs.time_s),
                )
            )
            batch.append(
                (
                    messages.TOPIC_APPLIED_COMMAND,
                    messages.applied_command_message(
                        Command(1e-3, 0.25 * (i % 4), 0.0), obs.time_s
                    ),
                )
            )
            batch.append(
                (
                    messages.TOPIC_CMD_COMMAND,
                    messages.command_message(Command(1e-3, 0.25 * (i % 4), 0.0), obs.time_s),
                )
            )
            for topic, msg in batch:
                if topic in self.pubs:
                    self.pubs[topic].publish(msg)
            time.sleep(0.002)
        for pub in self.pubs.values():
            wait_acked(pub)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def start_recorder(
    tmp_path: Path, domain: int, topics: list[str] | None = None
) -> tuple[subprocess.Popen, Path]:
    out = tmp_path / 'rec.mcap'
    env = isolated_environment(domain)
    args = [sys.executable, '-m', 'pulsejet_sim.ros.recorder']
    args += ['--ros-args', '-p', f'output:={out}']
    if topics is not None:
        args += ['-p', 'topics:=[' + ','.join(f"'{t}'" for t in topics) + ']']
    proc = subprocess.Popen(
        args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    line = proc.stdout.readline()
    assert line.startswith('recorder: writing'), line + proc.stderr.read()
    return proc, out


def read_all(path: Path) -> dict[str, list]:
    found: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages():
            found.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return found


@pytest.fixture
def localhost_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


@pytest.mark.timeout(60)
def test_recorder_process_records_all_topics_until_sigint(
    tmp_path: Path, localhost_only: None
) -> None:
    domain = domain_id(0)
    proc, out = start_recorder(tmp_path, domain)
    pub = Publisher(domain, list(messages.TOPIC_TYPES))
    try:
        pub.wait_matched()
        pub.publish_run()  # acknowledged: the recorder writes them although it stops now
    finally:
        pub.close()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=15)
    assert proc.returncode == 0, stderr
    assert f'to {out}' in stdout
    found = read_all(out)
    assert set(found) == {t if t.startswith('/') else '/' + t for t in messages.TOPIC_TYPES}
    assert {t: len(v) for t, v in found.items() if t != '/clock'} == {
        t: N_STEPS for t in found if t != '/clock'
    }
    assert len(found['/clock']) >= N_STEPS - 2  # best-effort subscription
    assert [m.twist.linear.x for m in found['/pulsejet/velocity']] == [
        0.1 * i for i in range(N_STEPS)
    ]
    assert [m.wrench.force.x for m in found['/pulsejet/thrust']] == [
        0.25 * i for i in range(N_STEPS)
    ]
    stamps = [
        m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in found['/pulsejet/velocity']
    ]
    assert stamps == pytest.approx([0.02 * i for i in range(N_STEPS)])
    assert [m.data for m in found['/pulsejet/cmd/valve']] == [
        0.25 * (i % 4) for i in range(N_STEPS)
    ]
    ledger = found['/pulsejet/energy_ledger'][-1].status[0]
    assert ledger.values[0].key == 'in_actuation_work' and float(ledger.values[0].value) == 0.5 * (
        N_STEPS - 1
    )


@pytest.mark.timeout(60)
def test_recorder_records_diagnostics_and_the_marker_by_default(
    tmp_path: Path, localhost_only: None
) -> None:
    """The node's default topics include /diagnostics and pulsejet/mantle_marker."""
    from diagnostic_msgs.msg import DiagnosticArray
    from visualization_msgs.msg import Marker

    domain = domain_id(4)
    proc, out = start_recorder(tmp_path, domain)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = Node('test_view_publisher', context=context)
    qos = messages.reliable_qos('x', 10)
    pubs = {
        '/diagnostics': node.create_publisher(DiagnosticArray, '/diagnostics', qos),
        '/pulsejet/mantle_marker': node.create_publisher(Marker, 'pulsejet/mantle_marker', qos),
    }
    try:
        deadline = time.monotonic() + 30
        while any(p.get_subscription_count() == 0 for p in pubs.values()):
            assert time.monotonic() < deadline, 'the recorder did not subscribe both'
            time.sleep(0.05)
        pubs['/diagnostics'].publish(
            messages.health_message('OK', 'pulsejet: /sim_node', '/sim_node', 'ok', {}, 0.5)
        )
        pubs['/pulsejet/mantle_marker'].publish(
            messages.mantle_marker([0.0, 0.02, 0.0], [0.05, 0.0, -0.05], 0.5, 'base_link')
        )
        for pub in pubs.values():
            wait_acked(pub)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=15)
    assert proc.returncode == 0, stderr
    found = read_all(out)
    assert found['/diagnostics'][0].status[0].name == 'pulsejet: /sim_node'
    marker = found['/pulsejet/mantle_marker'][0]
    assert marker.type == Marker.TRIANGLE_LIST and len(marker.points) == 2 * 6 * 24


@pytest.mark.timeout(60)
def test_recorder_topic_subset_and_sigterm(tmp_path: Path, localhost_only: None) -> None:
    domain = domain_id(1)
    topics = ['pulsejet/velocity', 'pulsejet/volume']
    proc, out = start_recorder(tmp_path, domain, topics)
    pub = Publisher(domain, topics + ['pulsejet/thrust'])
    try:
        deadline = time.monotonic() + 15
        while any(pub.pubs[t].get_subscription_count() == 0 for t in topics):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        for i in range(N_STEPS):
            for topic, msg in messages.observation_messages(observation(i)):
                if topic in pub.pubs:
                    pub.pubs[topic].publish(msg)
        for topic in topics:
            wait_acked(pub.pubs[topic])
    finally:
        pub.close()
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=15)
    assert proc.returncode == 0, stderr
    found = read_all(out)
    assert {t: len(v) for t, v in found.items()} == {
        '/pulsejet/velocity': N_STEPS,
        '/pulsejet/volume': N_STEPS,
    }


def test_parse_topics_names_bad_entry() -> None:
    assert parse_topics(['/pulsejet/velocity', 'x:std_msgs/msg/String']) == {
        '/pulsejet/velocity': 'geometry_msgs/msg/TwistStamped',
        'x': 'std_msgs/msg/String',
    }
    with pytest.raises(ValueError, match="'pulsejet/speed' is not a pulsejet topic"):
        parse_topics(['pulsejet/speed'])


@pytest.mark.timeout(30)
def test_recorder_class_in_process(tmp_path: Path, localhost_only: None) -> None:
    """The in-process Recorder (as demo.py may use it) with a publisher in the same context."""
    context = rclpy.Context()
    rclpy.init(
        context=context, domain_id=domain_id(2), signal_handler_options=SignalHandlerOptions.NO
    )
    try:
        node = Node('recorder_in_process', context=context)
        # send times need the message info, which this single-threaded executor passes
        recorder = Recorder(node, tmp_path / 'in.mcap', ['pulsejet/thrust'], send_times=True)
        pub = node.create_publisher(
            messages.message_class('pulsejet/thrust'), 'pulsejet/thrust', 10
        )
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        # the recorder subscribes once it discovers the publisher (its timer, on this executor)
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert set(recorder.subscriptions) == {'/pulsejet/thrust'}
        sent_between = []  # (before, after) each publish, system clock ns
        for i in range(5):
            before = time.time_ns()
            pub.publish(messages.observation_messages(observation(i))[3][1])
            sent_between.append((before, time.time_ns()))
            time.sleep(0.01)  # apart, so each send time falls in its own window only
        deadline = time.monotonic() + 10
        while (
            recorder.message_counts.get('/pulsejet/thrust', 0) < 5 and time.monotonic() < deadline
        ):
            executor.spin_once(timeout_sec=0.05)
        path = recorder.close()
        recorder.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert [m.wrench.force.x for m in read_all(path)['/pulsejet/thrust']] == [
        0.25 * i for i in range(5)
    ]
    # as rosbag2 records: publish_time is the middleware's send time (inside its publish() call),
    # log_time the receive time, never earlier
    from mcap.reader import make_reader

    with open(path, 'rb') as fh:
        records = [r for _, _, r in make_reader(fh).iter_messages()]
    assert len(records) == 5
    for (before, after), r in zip(sent_between, records):
        assert before <= r.publish_time <= after, (before, r.publish_time, after)
        assert r.publish_time <= r.log_time, (r.publish_time, r.log_time)


@pytest.mark.timeout(60)
def test_recorder_gets_applied_command_published_before_it_matched(
    tmp_path: Path, localhost_only: None
) -> None:
    """The held command goes out once at t=0; a recorder that matches later still records it."""
    domain = domain_id(3)
    topic = messages.TOPIC_APPLIED_COMMAND
    pub = Publisher(domain, [topic])
    proc = None
    try:
        held = Command(2e-4, 0.5, 0.0)
        pub.pubs[topic].publish(messages.applied_command_message(held, 0.0))
        proc, out = start_recorder(tmp_path, domain, [topic])
        pub.wait_matched()
        wait_acked(pub.pubs[topic])
    finally:
        pub.close()
        if proc is not None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=15)
    assert proc.returncode == 0
    (recorded,) = read_all(out)['/' + topic]
    assert messages.command_from_applied(recorded) == (0.0, held)


def test_subscription_qos_records_every_publisher_as_rosbag2_does() -> None:
    from pulsejet_sim.ros.recorder import subscription_qos
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    def offered(reliability, durability=DurabilityPolicy.VOLATILE):
        return QoSProfile(depth=10, reliability=reliability, durability=durability)

    reliable, best_effort = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
    latched = offered(reliable, DurabilityPolicy.TRANSIENT_LOCAL)
    qos = subscription_qos([offered(reliable), offered(reliable)])
    assert (qos.reliability, qos.durability) == (reliable, DurabilityPolicy.VOLATILE)
    # one best-effort publisher (a bag player's /clock): a reliable subscription would miss it
    assert subscription_qos([offered(reliable), offered(best_effort)]).reliability == best_effort
    qos = subscription_qos([latched])
    assert (qos.reliability, qos.durability) == (reliable, DurabilityPolicy.TRANSIENT_LOCAL)
    # a volatile publisher beside a latched one: a transient-local subscription would miss it
    assert subscription_qos([latched, offered(reliable)]).durability == DurabilityPolicy.VOLATILE


@pytest.mark.timeout(150)
def test_sim_node_waiting_for_every_topic_gives_a_recording_from_t0(
    tmp_path: Path, localhost_only: None
) -> None:
    """
    sim_node with wait_for_topics ['*'] (the launch file's record:=true) and a recorder.

    sim_node starts first and holds t = 0 until the recorder subscribed every topic it publishes:
    every state topic is recorded from t = 0, each with one message per state.
    """
    from pulsejet_sim.ros.node_params import node_command

    domain = domain_id(5)
    env = isolated_environment(domain)
    sim_log = tmp_path / 'sim_node.log'
    with open(sim_log, 'wb') as log:
        sim = subprocess.Popen(
            node_command(
                'pulsejet_sim.ros.sim_node',
                {'scene': 'pump_cycle', 'duration_s': 0.3, 'wait_timeout_s': 100.0},
            )
            + ['-p', "wait_for_topics:=['*']"],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    time.sleep(1.0)  # sim_node is up (and waiting) before the recorder is
    proc, out = start_recorder(tmp_path, domain)
    try:
        sim.wait(timeout=120)
    finally:
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=15)
    assert sim.returncode == 0, sim_log.read_text()[-3000:]
    assert proc.returncode == 0, stderr
    found = read_all(out)
    per_state = [
        '/pulsejet/velocity',
        '/pulsejet/thrust',
        '/pulsejet/volume',
        '/pulsejet/fluid_mass',
        '/pulsejet/mantle_radius',
        '/odom',
    ]
    n_states = 31  # t = 0, 0.01, ..., 0.3 s at pump_cycle's 100 Hz
    for topic in per_state:
        assert len(found.get(topic, [])) == n_states, (topic, len(found.get(topic, [])))
    for topic in ('/pulsejet/velocity', '/pulsejet/thrust', '/odom'):
        first = found[topic][0].header.stamp
        assert (first.sec, first.nanosec) == (0, 0), (topic, first)
    assert len(found['/clock']) >= n_states - 2  # best-effort subscription
    assert found['/pulsejet/applied_command'][0].header.stamp.sec == 0
