"""
The executor every pulsejet process spins (pulsejet_sim.ros.executor), in-process, real DDS.

What the nodes rely on from it: wall-clock timers on time (sim_node's diagnostics, the
recorder's flush); timers on simulated time with the single-threaded executor that
controller_node keeps; a callback's exception reaches the caller of spin_once (node_main turns it
into exit code 2, never a silent loss); the choice can be overridden.
"""

import time

from conftest import isolate_ros
from pulsejet_sim.ros.executor import EXECUTOR_ENV, executor_kind, make_executor
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

DOMAIN_OFFSET = 87
TIMER_PERIOD_S = 0.02
SIM_SECONDS = 1.0


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
    # never twice in one period (a late one may be followed by a short gap: the grid is kept)
    assert 17 <= len(fired) <= 21 and all(g > 0.05 for g in gaps), gaps


@pytest.mark.timeout(120)
def test_a_node_clock_timer_runs_on_simulated_time_with_the_controllers_executor(context):
    kind = 'single'  # controller_node's (run_node(..., executor_kind='single'))
    node = rclpy.create_node(
        'sim_time_timer',
        context=context,
        parameter_overrides=[Parameter('use_sim_time', Parameter.Type.BOOL, True)],
    )
    clock_node = rclpy.create_node('clock_source', context=context)
    fired_at_s = []
    node.create_timer(
        TIMER_PERIOD_S, lambda: fired_at_s.append(node.get_clock().now().nanoseconds * 1e-9)
    )
    pub = clock_node.create_publisher(
        Clock, '/clock', QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    )
    executor = make_executor(context=context, kind=kind)
    executor.add_node(node)
    executor.add_node(clock_node)
    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        steps = int(round(SIM_SECONDS / 1e-3))
        for k in range(1, steps + 1):
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(k * 1_000_000, 1_000_000_000)
            pub.publish(msg)
            executor.spin_once(timeout_sec=0.002)
        end = time.monotonic() + 2.0  # wall time passes: a wall-clock timer would keep firing
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        clock_node.destroy_node()
    # fired on the simulated clock only: every firing reads a simulated time, none after its end
    assert fired_at_s and max(fired_at_s) <= SIM_SECONDS + 1e-9, fired_at_s[-5:]
    expected = SIM_SECONDS / TIMER_PERIOD_S
    assert 0.8 * expected <= len(fired_at_s) <= expected + 1, len(fired_at_s)


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
