"""
Two robots in one ROS domain, each under a namespace of its own.

Two robots in one ROS domain: `--ros-args -r __ns:=/robotN` puts every topic, service and the
diagnostic status of each sim_node under its own name; each publishes nav_msgs/Odometry with the
configured REP 105 frames. Real processes, real DDS.
"""

import subprocess
import time

from conftest import isolate_ros
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from pulsejet_sim.ros.node_params import node_command
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy


@pytest.mark.timeout(180)
def test_two_namespaced_robots_in_one_domain(monkeypatch, tmp_path):
    domain = isolate_ros(monkeypatch, 57)
    procs = []
    # robot1 by frame_prefix (as robot_state_publisher's), robot2 by naming both frames
    for ns, frames in (
        ('robot1', {'frame_prefix': 'robot1/'}),
        ('robot2', {'base_frame_id': 'robot2/base_link', 'odom_frame_id': 'robot2/odom'}),
    ):
        cmd = node_command(
            'pulsejet_sim.ros.sim_node', {'scene': 'pump_cycle', **frames}
        ) + ['-r', f'__ns:=/{ns}']
        log = open(tmp_path / f'{ns}.log', 'wb')
        procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log))
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('namespace_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    odometry, velocity, statuses = {}, {}, set()
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    for ns in ('robot1', 'robot2'):
        node.create_subscription(
            Odometry, f'/{ns}/odom', lambda m, ns=ns: odometry.setdefault(ns, m), qos
        )
        node.create_subscription(
            TwistStamped,
            f'/{ns}/pulsejet/velocity',
            lambda m, ns=ns: velocity.setdefault(ns, m),
            qos,
        )
    node.create_subscription(
        DiagnosticArray, '/diagnostics', lambda m: statuses.update(s.name for s in m.status), qos
    )
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and not (
            len(odometry) == 2 and len(velocity) == 2 and len(statuses) >= 2
        ):
            executor.spin_once(timeout_sec=0.05)
        names = {name for name, _ in node.get_topic_names_and_types()}
        for ns in ('robot1', 'robot2'):
            for topic in (
                'odom',
                'pulsejet/velocity',
                'pulsejet/volume',
                'pulsejet/applied_command',
                'pulsejet/cmd/command',
                'pulsejet/cmd/pump_flow',
            ):
                assert f'/{ns}/{topic}' in names, (ns, topic, sorted(names))
        services = {name for name, _ in node.get_service_names_and_types()}
        assert {'/robot1/pulsejet/reset', '/robot2/pulsejet/reset'} <= services
        assert {'pulsejet: /robot1/sim_node', 'pulsejet: /robot2/sim_node'} <= statuses, statuses
        for ns in ('robot1', 'robot2'):
            assert odometry[ns].header.frame_id == f'{ns}/odom'
            assert odometry[ns].child_frame_id == f'{ns}/base_link'
            assert odometry[ns].pose.pose.orientation.w == 1.0
            # one body frame for everything body-fixed
            assert velocity[ns].header.frame_id == f'{ns}/base_link'
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        for proc, log in procs:
            proc.terminate()
            proc.wait(20)
            log.close()
    for proc, _ in procs:
        assert proc.returncode == 0, (tmp_path / 'robot1.log').read_text()[-2000:]


@pytest.mark.timeout(180)
def test_shell_mantle_marker_is_the_revolved_meridian(monkeypatch, tmp_path):
    """
    The shell robot publishes its mantle surface as the revolved meridian.

    sim_node (shell robot) publishes the mantle surface as a TRIANGLE_LIST Marker in the body
    frame: every vertex lies on a circle of a meridian node's radius about the swimming axis.
    """
    import math

    from geometry_msgs.msg import PolygonStamped
    from pulsejet_sim.ros import messages
    from visualization_msgs.msg import Marker

    domain = isolate_ros(monkeypatch, 59)
    log = open(tmp_path / 'sim.log', 'wb')
    proc = subprocess.Popen(
        node_command('pulsejet_sim.ros.sim_node', {'scene': 'shell_robot'}),
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('marker_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got = {}
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        Marker, messages.TOPIC_MANTLE_MARKER, lambda m: got.__setitem__('marker', m), qos
    )
    profiles = {}
    node.create_subscription(
        PolygonStamped,
        messages.TOPIC_MANTLE_PROFILE,
        lambda m: profiles.__setitem__((m.header.stamp.sec, m.header.stamp.nanosec), m),
        qos,
    )
    try:
        end = time.monotonic() + 120

        def stamp_of(msg):
            return (msg.header.stamp.sec, msg.header.stamp.nanosec)

        # a marker whose state's profile arrived too (the two subscriptions match one after the
        # other: on a loaded machine the first markers can come before the profiles do)
        while time.monotonic() < end and not (
            'marker' in got and stamp_of(got['marker']) in profiles
        ):
            executor.spin_once(timeout_sec=0.05)
        marker = got['marker']
        assert (
            marker.type == Marker.TRIANGLE_LIST
            and marker.header.frame_id == messages.BASE_FRAME_ID
        )
        assert profiles[stamp_of(marker)].header.frame_id == marker.header.frame_id
        profile = profiles[stamp_of(marker)].polygon.points  # same state
        assert len(marker.points) == 6 * messages.MANTLE_MARKER_SEGMENTS * (len(profile) - 1)
        meridian = {
            (round(p.x, 5), round(p.y, 5)) for p in profile
        }  # (axial, radius) of each node
        assert {(round(p.x, 5), round(math.hypot(p.y, p.z), 5)) for p in marker.points} == meridian
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        proc.wait(20)
        log.close()
    assert proc.returncode == 0, (tmp_path / 'sim.log').read_text()[-2000:]
