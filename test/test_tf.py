"""
sim_node's odom -> body transform on /tf, with the real tf2_msgs message type.

The PyPI install has no tf2_msgs, so a session fixture builds its TFMessage from the definition
with the venv's rosidl toolchain (test/tf2_msgs_build.py); sim_node then imports it and
broadcasts, a subscriber here receives it over real DDS, and its CDR is decoded a second time with
rosbags' own Jazzy definition of tf2_msgs/msg/TFMessage (so the built type is the standard one on
the wire).
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import subprocess
import sys
import time

from conftest import isolate_ros
from pulsejet_sim.ros.node_params import node_command
import pytest

rclpy = pytest.importorskip('rclpy')
from nav_msgs.msg import Odometry  # noqa: E402, I100
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DOMAIN_OFFSET = 93
QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope='session')
def tf2_msgs_paths(tmp_path_factory):
    """(python path, library path) of a tf2_msgs built here, or the installed one's ('', '')."""
    try:
        import tf2_msgs.msg  # noqa: F401  (a ROS install: nothing to build)

        return '', ''
    except ImportError:
        pass
    if shutil.which('gcc') is None or shutil.which('g++') is None:
        pytest.skip('no C/C++ compiler to build tf2_msgs from its definition')
    import tf2_msgs_build

    python_path, library_path = tf2_msgs_build.build(tmp_path_factory.mktemp('tf2_msgs'))
    return str(python_path), str(library_path)


def prepend(variable: str, path: str) -> str:
    old = os.environ.get(variable, '')
    return f'{path}{os.pathsep}{old}' if old and path else (path or old)


@pytest.mark.timeout(240)
def test_tf_carries_odom_to_body_with_prefixed_frames(monkeypatch, tmp_path, tf2_msgs_paths):
    python_path, library_path = tf2_msgs_paths
    domain = isolate_ros(monkeypatch, DOMAIN_OFFSET)
    if python_path:
        monkeypatch.syspath_prepend(python_path)
        monkeypatch.setenv('PYTHONPATH', prepend('PYTHONPATH', python_path))
        # the type support dispatcher dlopens its implementations by name: sim_node finds them
        # on this path; this process read LD_LIBRARY_PATH when it started, so it loads them
        # first (a loaded library is found by its name)
        monkeypatch.setenv('LD_LIBRARY_PATH', prepend('LD_LIBRARY_PATH', library_path))
        import ctypes

        for kind in ('generator_c', 'typesupport_introspection_c', 'typesupport_fastrtps_c'):
            ctypes.CDLL(str(Path(library_path) / f'libtf2_msgs__rosidl_{kind}.so'), os.RTLD_GLOBAL)
    from rosbags.typesys import get_typestore, Stores
    from tf2_msgs.msg import TFMessage

    log_path = tmp_path / 'sim.log'
    log = open(log_path, 'wb')
    proc = subprocess.Popen(
        node_command('pulsejet_sim.ros.sim_node', {'scene': 'pump_cycle', 'frame_prefix': 'r1/'})
        + ['-r', '__ns:=/robot1'],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=ROOT,
    )
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('tf_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    raw_tf, odometry = [], {}
    node.create_subscription(TFMessage, '/tf', raw_tf.append, QOS, raw=True)
    node.create_subscription(
        Odometry,
        '/robot1/odom',
        lambda m: odometry.__setitem__((m.header.stamp.sec, m.header.stamp.nanosec), m),
        QOS,
    )
    try:
        end = time.monotonic() + 150
        while time.monotonic() < end and len(raw_tf) < 50:
            executor.spin_once(timeout_sec=0.05)
            assert proc.poll() is None, log_path.read_text()[-3000:]
        assert len(raw_tf) >= 50, log_path.read_text()[-3000:]
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        proc.wait(30)
        log.close()
    out = log_path.read_text()
    assert proc.returncode == 0, out[-3000:]
    assert 'tf2_msgs is not installed' not in out, out[-3000:]

    store = get_typestore(Stores.ROS2_JAZZY)
    from rclpy.serialization import deserialize_message

    matched = 0
    for data in raw_tf:
        ours = deserialize_message(data, TFMessage)
        theirs = store.deserialize_cdr(data, 'tf2_msgs/msg/TFMessage')
        (t,) = ours.transforms
        (u,) = theirs.transforms
        assert (t.header.frame_id, t.child_frame_id) == ('r1/odom', 'r1/base_link')
        assert (u.header.frame_id, u.child_frame_id) == ('r1/odom', 'r1/base_link')
        assert u.transform.translation.x == t.transform.translation.x
        assert (t.transform.rotation.w, u.transform.rotation.w) == (1.0, 1.0)
        odom = odometry.get((t.header.stamp.sec, t.header.stamp.nanosec))
        if odom is not None:  # the transform is the odometry's pose of the same state
            matched += 1
            assert t.transform.translation.x == odom.pose.pose.position.x
            assert odom.child_frame_id == t.child_frame_id
    assert matched >= 40, matched
    stamps = [
        deserialize_message(d, TFMessage).transforms[0].header.stamp for d in raw_tf
    ]
    times = [s.sec + 1e-9 * s.nanosec for s in stamps]
    assert all(b > a for a, b in zip(times, times[1:])), times[:10]  # one per state, in order


@pytest.mark.timeout(120)
def test_without_tf2_msgs_the_node_says_there_is_no_tf(monkeypatch, tmp_path):
    isolate_ros(monkeypatch, DOMAIN_OFFSET + 1)
    # asked in a fresh process: this one may hold the tf2_msgs built for the test above
    if subprocess.run([sys.executable, '-c', 'import tf2_msgs.msg'], cwd=ROOT).returncode == 0:
        pytest.skip('tf2_msgs is installed here')
    proc = subprocess.run(
        node_command('pulsejet_sim.ros.sim_node', {'scene': 'pump_cycle', 'duration_s': 0.05}),
        capture_output=True,
        text=True,
        timeout=100,
        cwd=ROOT,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert 'no /tf: tf2_msgs is not installed' in out, out[-3000:]
