"""
The real sim_node (a subprocess) against an in-process probe node over DDS.

Every test runs in a ROS domain derived from the pytest pid, with localhost-only discovery.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time

from conftest import isolate_ros
import numpy as np
from pulsejet_sim.ros.launching import NodeProcess
import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from geometry_msgs.msg import TwistStamped, WrenchStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

DOMAIN_OFFSET = 0
QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


def stamp_s(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


@pytest.fixture
def ros_domain(monkeypatch):
    return isolate_ros(monkeypatch, DOMAIN_OFFSET)


@pytest.fixture
def start_node(ros_domain, tmp_path):
    started = []

    def start(module='pulsejet_sim.ros.sim_node', **params):
        # these tests exercise the pump/valve vehicle; the nodes' default scene is the shell robot
        params.setdefault('scene', 'pump_cycle')
        log_path = tmp_path / f'{module}.{len(started)}.log'
        p = NodeProcess(module, params, log_path, dict(os.environ))
        started.append(p)
        return p

    yield start
    for p in started:
        p.stop(timeout_s=5.0)


class Probe:
    """In-process node: subscribes to the simulator's topics and publishes commands."""

    def __init__(self, domain: int):
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context,
            domain_id=domain,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
        self.node = rclpy.create_node('probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received = {}
        topics = {
            '/clock': Clock,
            'pulsejet/volume': Float64,
            'pulsejet/mantle_radius': Float64,
            'pulsejet/fluid_mass': Float64,
            'pulsejet/velocity': TwistStamped,
            'pulsejet/thrust': WrenchStamped,
            'pulsejet/energy_ledger': DiagnosticArray,
            '/diagnostics': DiagnosticArray,
        }
        for topic, msg_type in topics.items():
            self.received[topic] = []
            self.node.create_subscription(msg_type, topic, self._store(topic), QOS)
        self.pub = {
            name: self.node.create_publisher(Float64, f'pulsejet/cmd/{name}', QOS)
            for name in ('pump_flow', 'valve', 'cable_force')
        }

    def _store(self, topic):
        def cb(msg):
            self.received[topic].append((time.monotonic(), msg))

        return cb

    def spin_for(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)

    def spin_until(self, predicate, timeout: float, what: str = 'condition'):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return
            self.executor.spin_once(timeout_sec=0.02)
        raise AssertionError(f'timed out after {timeout:g} s waiting for {what}')

    def clock_s(self) -> float:
        msgs = self.received['/clock']
        return stamp_s(msgs[-1][1].clock) if msgs else -1.0

    def last(self, topic):
        return self.received[topic][-1][1] if self.received[topic] else None

    def send(self, name: str, value: float):
        self.pub[name].publish(Float64(data=float(value)))

    def wait_for_subscribers(self, timeout=20.0):
        self.spin_until(
            lambda: all(p.get_subscription_count() > 0 for p in self.pub.values()),
            timeout,
            'sim_node to subscribe to the command topics',
        )

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def probe(ros_domain):
    p = Probe(ros_domain)
    yield p
    p.close()


def wait_running(probe, sim, t_min=0.2, timeout=60.0):
    """Until /clock passed t_min (scene loading + JIT may take a while on a cold cache)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        probe.spin_for(0.1)
        assert sim.alive(), f'sim_node died:\n{sim.output()[-3000:]}'
        if probe.clock_s() >= t_min:
            return
    raise AssertionError(f'/clock did not reach {t_min} s in {timeout} s:\n{sim.output()[-3000:]}')


@pytest.mark.timeout(120)
def test_publishes_every_topic_stamped_with_sim_time(start_node, probe):
    sim = start_node(real_time_factor=1.0, publish_rate_hz=50.0)
    wait_running(probe, sim, 0.2)
    wall0, sim0 = time.monotonic(), probe.clock_s()
    probe.spin_for(1.5)
    wall1, sim1 = time.monotonic(), probe.clock_s()
    assert sim.alive(), sim.output()[-3000:]

    # /clock advances at about the real-time factor and never goes back
    clocks = [stamp_s(m.clock) for _, m in probe.received['/clock']]
    assert all(b >= a for a, b in zip(clocks, clocks[1:])), 'clock went backwards'
    rate = (sim1 - sim0) / (wall1 - wall0)
    assert (
        0.6 < rate < 1.4
    ), f'sim time advanced {sim1 - sim0:.3f} s in {wall1 - wall0:.3f} s of wall time'

    for topic, msgs in probe.received.items():
        assert msgs, f'nothing received on {topic}'
    for topic in ('pulsejet/volume', 'pulsejet/mantle_radius', 'pulsejet/fluid_mass'):
        values = [m.data for _, m in probe.received[topic]]
        assert all(math.isfinite(v) for v in values), topic
        assert all(v > 0 for v in values), f'{topic} not positive: {values[:5]}'

    # headers carry simulation time: each stamp is one of the /clock instants, not wall time
    clock_set = {round(c, 9) for c in clocks}
    for topic in ('pulsejet/velocity', 'pulsejet/thrust'):
        stamps = [stamp_s(m.header.stamp) for _, m in probe.received[topic]]
        assert max(stamps) < 1e6, f'{topic} stamped with wall time: {stamps[-1]}'
        assert all(
            round(s, 9) in clock_set for s in stamps[1:-1]
        ), f'{topic} stamps not on the /clock instants: {stamps[:5]} vs {clocks[:5]}'
        # the body frame, as the odometry's
        assert probe.last(topic).header.frame_id == 'base_link'
    ledger = probe.last('pulsejet/energy_ledger')
    assert stamp_s(ledger.header.stamp) < 1e6
    # health and books are not places: no frame (as diagnostic_updater publishes them)
    assert ledger.header.frame_id == '' and probe.last('/diagnostics').header.frame_id == ''
    keys = {kv.key for kv in ledger.status[0].values}
    assert {'in_actuation_work', 'out_jet_kinetic', 'closure_error'} <= keys, keys
    n_ledger = len(probe.received['pulsejet/energy_ledger'])
    n_clock = len(probe.received['/clock'])
    assert (
        n_ledger < n_clock / 3
    ), f'ledger published {n_ledger} times vs {n_clock} clock messages (~5 Hz expected)'


def volume_series(probe, since_wall):
    return [m.data for t, m in probe.received['pulsejet/volume'] if t >= since_wall]


@pytest.mark.timeout(120)
def test_bad_commands_rejected_good_ones_applied(tmp_path):
    from pulsejet_sim.core.model_io import Command
    from pulsejet_sim.ros.harness import SimHarness

    with SimHarness(
        scene='pump_cycle',
        parameters={'real_time_factor': 1.0, 'publish_rate_hz': 50.0},
        log_dir=tmp_path,
    ) as h:
        h.wait_for(lambda s: s.time_s >= 0.3, 60.0)
        # idle (the scene's initial command: pump off): the cavity volume is at rest
        h.spin(0.5)
        v_rest = h.latest.volume_m3

        bad = [
            ('pump_flow_m3_s', float('nan'), 'nan'),
            ('pump_flow_m3_s', float('inf'), 'inf'),
            ('pump_flow_m3_s', -1.0, '-1.0'),
            ('valve_opening', 2.0, '2.0'),
            ('valve_opening', float('nan'), 'nan'),
            ('cable_force_n', -5.0, '-5.0'),
        ]
        t_bad = time.monotonic()
        for field, value, _ in bad:
            h.send(**{field: value})
            h.spin(0.1)
        h.spin(1.0)
        out = h.output()
        for field, _, text in bad:
            low, high = Command.LIMITS[field]
            expected = f'{field}={text}'
            assert any(
                expected in line and f'[{low}, {high}]' in line and 'WARN' in line
                for line in out.splitlines()
            ), f'no warning naming {expected} and [{low}, {high}]:\n{out[-3000:]}'
        after = [s.volume_m3 for s in h.states if s.wall_s >= t_bad]
        assert after and all(
            math.isfinite(v) for v in after
        ), 'non-finite volume after bad commands'
        assert max(abs(v - v_rest) for v in after) <= 0.01 * abs(v_rest) + 1e-12, (
            f'state changed after rejected commands: rest {v_rest}, after'
            f' {min(after)}..{max(after)}'
        )
        assert h.latest.time_s > 0.5

        # a valid command takes effect: valve shut + pump on inflates the cavity
        low, high = Command.LIMITS['pump_flow_m3_s']
        flow = min(high, max(1e-4, abs(v_rest) * 0.5))  # about half the rest volume per second
        h.send(valve_opening=0.0, pump_flow_m3_s=flow)
        h.wait_for(
            lambda s: s.volume_m3 > v_rest * 1.05,
            10.0,
            f'the volume to rise above {v_rest * 1.05:.3e} m^3 with pump {flow:.3e} m^3/s',
        )
        assert 'WARN' not in h.output()[len(out):], h.output()[len(out):]


@pytest.mark.timeout(120)
def test_exits_after_duration(start_node):
    sim = start_node(duration_s=0.5, real_time_factor=2)  # an integer is accepted for a number
    sim.proc.wait(timeout=90)
    out = sim.output()
    assert sim.proc.returncode == 0, out[-3000:]
    assert 'duration 0.5 s of simulated time reached' in out, out[-3000:]


GC_PROBE = """
import gc
import sys

from pulsejet_sim.ros.node_main import run_node
from rclpy.node import Node


class Probe(Node):
    def __init__(self):
        super().__init__('gc_probe')
        self.done = False

    def start(self):
        print('objects frozen before start:', gc.get_freeze_count(), flush=True)
        self.done = True


sys.exit(run_node('gc_probe', Probe))
"""


@pytest.mark.timeout(120)
def test_start_up_objects_are_frozen_before_the_node_starts(ros_domain):
    """
    run_node's full collection comes before start(), so no pacing thread waits behind it.

    It holds the interpreter 0.1-0.2 s: run after start(), sim_node's first tick came that late
    and every start logged 'fell behind real time ... no step computed yet'.
    """
    proc = subprocess.run(
        [sys.executable, '-c', GC_PROBE], capture_output=True, text=True, timeout=100
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    frozen = [line for line in proc.stdout.splitlines() if 'frozen before start' in line]
    assert frozen and int(frozen[0].split(':')[1]) > 10_000, proc.stdout[-2000:]


@pytest.mark.timeout(120)
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_clean_shutdown_on_signal(start_node, probe, sig):
    sim = start_node()
    wait_running(probe, sim, 0.1)
    code = sim.stop(timeout_s=10.0, sig=sig)  # a node that does not exit fails here
    assert code == 0, f'exit code {code} on {sig.name}:\n{sim.output()[-3000:]}'
    assert 'Traceback' not in sim.output(), sim.output()[-3000:]


@pytest.mark.timeout(60)
def test_rejects_invalid_parameter(start_node):
    sim = start_node(real_time_factor=-1.0)
    sim.proc.wait(timeout=50)
    assert sim.proc.returncode != 0
    assert 'real_time_factor' in sim.output(), sim.output()[-3000:]


@pytest.mark.timeout(120)
def test_blow_up_stops_stepping_without_nan(tmp_path):
    """
    A blow-up stops stepping and publishing, never publishes NaN; the node stays up.

    Paper 001's equations as written (escape, paper coupling) collapse the shell at ~3 s: the
    node logs the cause, stops stepping and publishing, never publishes NaN and stays up. (A pump
    can no longer over-inflate the shell: its pressure-flow curve stalls it.)
    """
    from pulsejet_sim.ros.harness import SimHarness

    with SimHarness(
        scene='escape',
        parameters={
            'real_time_factor': 2.0,
            'publish_rate_hz': 50.0,
            # paused until the harness is matched: discovery on a loaded machine can take
            # longer than the 1.5 s of wall time this scene needs to blow up
            'start_paused': True,
            'scene_overrides': {'options': {'coupling': 'paper'}},
        },
        log_dir=tmp_path,
    ) as h:
        h.resume()
        h.wait_for(lambda s: s.time_s >= 0.1, 60.0)
        h.spin_until(lambda: 'physics blew up' in h.output(), 30.0, 'the physics to blow up')
        h.spin(0.5)
        t_stop, n_clock = h.latest.time_s, len(h.states)
        h.spin(1.0)
        assert h.processes[
            'sim_node'
        ].alive(), f'sim_node died on a blow-up:\n{h.output()[-3000:]}'
        line = next(ln for ln in h.output().splitlines() if 'physics blew up' in ln)
        assert 'ERROR' in line and 'semi-axis' in line, line
        assert (
            len(h.states) == n_clock and h.latest.time_s == t_stop
        ), 'still publishing after a blow-up'
        for s in h.states:
            assert all(
                math.isfinite(v)
                for v in (
                    s.volume_m3,
                    s.mantle_radius_m,
                    s.fluid_mass_kg,
                    s.velocity_m_s,
                    s.thrust_n,
                )
            ), s
    assert (
        h.exit_codes['sim_node'] == 1
    )  # the run failed: non-zero exit even when stopped by a signal


@pytest.mark.timeout(120)
def test_blow_up_with_duration_exits_non_zero(tmp_path):
    from pulsejet_sim.ros.harness import SimHarness

    with SimHarness(
        scene='escape',
        parameters={
            'real_time_factor': 2.0,
            'duration_s': 60.0,
            # paused until the harness is matched: discovery on a loaded machine can take
            # longer than the 1.5 s of wall time this scene needs to blow up
            'start_paused': True,
            'scene_overrides': {'options': {'coupling': 'paper'}},
        },
        log_dir=tmp_path,
    ) as h:
        h.resume()
        h.wait_for(lambda s: s.time_s >= 0.1, 60.0)
        assert h.wait_for_exit('sim_node', timeout_s=30.0) == 1, h.output()[-3000:]
        assert 'physics blew up' in h.output()


def send_clock_until(probe, clock_pub, stamp, answered, attempts=20):
    """
    Send the same /clock time again until controller_node answers it.

    controller_node takes /clock best effort (so that a bag player's clock works): a sample may
    be lost, so the same time is sent again until it answers (a repeated time sends nothing more).
    """
    for _ in range(attempts):
        clock_pub.publish(Clock(clock=stamp))
        try:
            probe.spin_until(answered, 0.5, 'a command')
            return
        except AssertionError:
            continue
    raise AssertionError(f'no command for the clock {stamp} after {attempts} sends')


@pytest.mark.timeout(120)
def test_controller_follows_clock_and_parameter_overrides(start_node, probe):
    """
    controller_node follows a /clock we publish, with parameters overridden.

    controller_node driven by a /clock we publish: the routine's phases in simulated time, with
    parameters overridden on the command line.
    """
    from builtin_interfaces.msg import Time

    ctrl = start_node(
        'pulsejet_ctrl.controller_node',
        pump_flow_m3_s=1.0e-3,
        inflate_s=0.5,
        hold_s=0.1,
        jet_s=0.4,
        cycles=1,
        rate_hz=50.0,
        target_volume_m3=0.0,
    )
    got = {'pump_flow': [], 'valve': [], 'cable_force': []}
    subs = [
        probe.node.create_subscription(
            Float64, f'pulsejet/cmd/{name}', lambda m, name=name: got[name].append(m.data), QOS
        )
        for name in got
    ]
    clock_pub = probe.node.create_publisher(Clock, '/clock', QOS)
    probe.spin_until(
        lambda: clock_pub.get_subscription_count() >= 2  # the probe's own + the controller's
        and all(s.get_publisher_count() > 0 for s in subs),
        60.0,
        'controller_node to match /clock and the command topics',
    )

    def at(t):
        n0 = len(got['valve'])
        ns = round(t * 1e9)

        send_clock_until(
            probe,
            clock_pub,
            Time(sec=ns // 10**9, nanosec=ns % 10**9),
            lambda: len(got['valve']) > n0
            and len(got['pump_flow']) > n0
            and len(got['cable_force']) > n0,
        )
        return got['pump_flow'][-1], got['valve'][-1], got['cable_force'][-1]

    assert at(0.0) == (1.0e-3, 0.0, 0.0)  # inflate: pump on, valve shut
    assert at(0.3) == (1.0e-3, 0.0, 0.0)
    assert at(0.55) == (0.0, 0.0, 0.0)  # hold
    assert at(0.7) == (0.0, 1.0, 0.0)  # jet
    assert at(1.2) == (0.0, 1.0, 0.0)  # done after 1 cycle: valve left open, pump off
    # no command between two rate ticks (50 Hz of simulated time)
    n = len(got['valve'])
    ns = round(1.205e9)
    clock_pub.publish(Clock(clock=Time(sec=ns // 10**9, nanosec=ns % 10**9)))
    probe.spin_for(0.3)
    assert len(got['valve']) == n
    assert ctrl.alive(), ctrl.output()[-3000:]
    assert ctrl.stop() == 0, ctrl.output()[-3000:]


@pytest.mark.timeout(120)
def test_controller_target_volume_mode(start_node, probe):
    """With target_volume_m3 > 0 the inflation ends when pulsejet/volume reaches the target."""
    from builtin_interfaces.msg import Time

    ctrl = start_node(
        'pulsejet_ctrl.controller_node',
        pump_flow_m3_s=1.0e-3,
        inflate_s=100.0,
        target_volume_m3=2.0e-3,
        hold_s=0.1,
        jet_s=0.4,
        cycles=0,
    )
    got = []
    sub = probe.node.create_subscription(
        Float64, 'pulsejet/cmd/pump_flow', lambda m: got.append(m.data), QOS
    )
    clock_pub = probe.node.create_publisher(Clock, '/clock', QOS)
    volume_pub = probe.node.create_publisher(Float64, 'pulsejet/volume', QOS)
    probe.spin_until(
        lambda: clock_pub.get_subscription_count() >= 2
        and volume_pub.get_subscription_count() >= 2
        and sub.get_publisher_count() > 0,
        60.0,
        'controller_node to match its topics',
    )

    def at(t, volume):
        for _ in range(3):  # best effort: the volume arrives before the clock tick that uses it
            volume_pub.publish(Float64(data=volume))
            probe.spin_for(0.1)
        n0 = len(got)
        ns = round(t * 1e9)
        send_clock_until(
            probe, clock_pub, Time(sec=ns // 10**9, nanosec=ns % 10**9), lambda: len(got) > n0
        )
        return got[-1]

    assert at(0.0, 1.0e-3) == 1.0e-3
    assert at(1.0, 1.9e-3) == 1.0e-3  # below the target: still inflating
    assert at(1.1, 2.05e-3) == 0.0  # target reached: hold
    assert ctrl.stop() == 0, ctrl.output()[-3000:]


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    'executor_parameter, executor_class',
    [({}, 'SingleThreadedExecutor'), ({'executor': 'events'}, 'EventsExecutor')],
    ids=['single-threaded-executor', 'events-executor'],
)
def test_lookahead_sends_every_state_once_in_order_through_a_reset(
    tmp_path, executor_parameter, executor_class
):
    """
    With lookahead_s every state is sent once, in order, also through a reset.

    With lookahead_s the physics runs ahead and a publishing thread sends each state at its wall
    time: every period arrives once, in order, and a reset flushes the states computed ahead (they
    are sent, not lost) before the clock goes back to 0. The same on the events executor
    (sim_node's `executor` parameter), which answers the reset from its own queue.
    """
    from pulsejet_sim.ros.harness import SimHarness

    period = 0.02
    with SimHarness(
        scene='pump_cycle',
        parameters={'publish_rate_hz': 1 / period, 'lookahead_s': 0.2, **executor_parameter},
        log_dir=tmp_path,
    ) as h:
        from std_srvs.srv import Trigger

        h.wait_for(lambda s: s.time_s >= 0.6, 60.0)
        assert f"spinning on rclpy's {executor_class}" in h.output(), h.output()[-2000:]
        last_received = h.latest.time_s
        t_call = time.monotonic()
        message = h.call('reset', Trigger.Request()).message
        t_computed = float(message.split('from t=')[1].split()[0])
        # the physics was ahead of what had been published
        assert t_computed > last_received + 0.05, (message, last_received)
        h.wait_for(lambda s: 0.3 <= s.time_s < 1.0, 60.0, since_wall=t_call)
        h.spin(0.2)
        times = np.array([s.time_s for s in h.states])
    steps = np.diff(times)
    back = np.flatnonzero(steps < 0)
    assert (
        back.size == 1
    ), f'the clock went back {back.size} times (expected once, at the reset): {times}'
    before, after = times[:back[0] + 1], times[back[0] + 1:]
    assert after[0] == 0.0
    for run in (before, after):
        assert np.allclose(np.diff(run), period, atol=1e-9), f'a state missing or repeated: {run}'
