"""
The executor the pulsejet processes spin (pulsejet_sim.ros.executor), in-process, real DDS.

What the nodes rely on from it: wall-clock timers never firing twice in a period (the
recorder's flush, controller_node's standby); a node clock on simulated time that follows /clock,
which controller_node's command schedule reads through its jump callbacks; a callback's exception
reaches the caller of spin_once (node_main turns it into exit code 2, never a silent loss); the
choice can be overridden.
"""

import sys
import time

from conftest import isolate_ros
from pulsejet_sim.ros.executor import EXECUTOR_ENV, executor_kind, make_executor
import pytest
import rclpy
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

DOMAIN_OFFSET = 87


@pytest.fixture
def context(monkeypatch):
    domain = isolate_ros(monkeypatch, DOMAIN_OFFSET)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_the_events_executor_is_the_default_and_the_env_can_override_it(monkeypatch, context):
    pytest.importorskip('rclpy.experimental')
    monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    assert executor_kind() == 'events'
    assert not isinstance(make_executor(context=context), SingleThreadedExecutor)
    monkeypatch.setenv(EXECUTOR_ENV, 'single')
    assert isinstance(make_executor(context=context), SingleThreadedExecutor)
    monkeypatch.setenv(EXECUTOR_ENV, 'multi')
    with pytest.raises(ValueError, match=r"PULSEJET_EXECUTOR='multi' rejected; allowed: one of"):
        make_executor(context=context)


def test_events_asked_for_by_name_without_rclpy_support_is_refused_with_the_reason(
    monkeypatch, context
):
    monkeypatch.setitem(sys.modules, 'rclpy.experimental', None)  # an rclpy without it
    with pytest.raises(ValueError, match=r"executor 'events' rejected: this rclpy has no"):
        make_executor(context=context, kind='events')
    assert executor_kind() == 'single'  # the default falls back instead


@pytest.mark.timeout(60)
def test_a_wall_clock_timer_fires_once_per_period(context):
    node = rclpy.create_node('wall_timer', context=context)
    fired = []
    node.create_timer(0.1, lambda: fired.append(time.monotonic()))
    executor = make_executor(context=context)
    executor.add_node(node)
    try:
        start = time.monotonic()
        while time.monotonic() < start + 2.0:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
    gaps = [b - a for a, b in zip(fired, fired[1:])]
    # never more than once a period (a loaded machine may make it miss some: rcl skips those, and
    # a late one may be followed by a short gap, the grid is kept)
    assert 3 <= len(fired) <= 21 and all(g > 0.05 for g in gaps), gaps


@pytest.mark.timeout(120)
def test_every_clock_update_reaches_a_jump_callback_of_a_sim_time_node(context):
    """Each /clock forward (and the jump back) reaches the callback, as controller_node needs."""
    node = rclpy.create_node(
        'sim_time_jumps',
        context=context,
        parameter_overrides=[Parameter('use_sim_time', Parameter.Type.BOOL, True)],
    )
    clock_node = rclpy.create_node('clock_source', context=context)
    seen_ns = []
    handle = node.get_clock().create_jump_callback(
        JumpThreshold(min_forward=Duration(nanoseconds=1), min_backward=Duration(nanoseconds=-1)),
        post_callback=lambda jump: seen_ns.append(node.get_clock().now().nanoseconds),
    )
    pub = clock_node.create_publisher(Clock, '/clock', QoSProfile(depth=10))
    executor = make_executor(context=context)
    executor.add_node(node)
    executor.add_node(clock_node)
    sent_ns = [k * 1_000_000 for k in range(1, 201)] + [5_000_000]  # 200 ms, then back to 5 ms
    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for ns in sent_ns:
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
            pub.publish(msg)
            end = time.monotonic() + 5.0
            while (not seen_ns or seen_ns[-1] != ns) and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.01)
    finally:
        executor.shutdown()
        del handle
        node.destroy_node()
        clock_node.destroy_node()
    assert seen_ns == sent_ns, (len(seen_ns), seen_ns[-3:])


@pytest.mark.timeout(60)
def test_a_callbacks_exception_reaches_the_caller_of_spin_once(context):
    node = rclpy.create_node('raises', context=context)
    node.create_subscription(Float64, 'boom', lambda msg: 1 / 0, 10)
    pub = node.create_publisher(Float64, 'boom', 10)
    executor = make_executor(context=context)
    executor.add_node(node)
    try:
        with pytest.raises(ZeroDivisionError):
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                pub.publish(Float64(data=1.0))
                executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
