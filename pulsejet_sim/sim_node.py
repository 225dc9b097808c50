"""ROS 2 node around `Simulation`: steps the physics in (scaled) real time and publishes every topic.

A thin adapter: the physics lives in `pulsejet_sim.simulation`, the message layout in
`pulsejet_sim.messages`. This module only paces, validates commands and publishes.

Parameters
  scene                  (string, read-only)  scene name under config/ or a YAML path; default pump_cycle
  real_time_factor       (double > 0)         simulated seconds per wall-clock second; default 1.0
  publish_rate_hz        (double > 0)         publication rate (wall clock); default: scene value or 100
  duration_s             (double >= 0)        simulated time after which the node exits (0 = forever)
  wait_for_subscribers   (int >= 0)           hold the clock at 0 until `/clock` has this many
                                              subscribers (at most wait_timeout_s wall seconds)
  wait_timeout_s         (double >= 0)        see wait_for_subscribers; default 10

Publishes (stamped with simulation time, frame pulsejet/body): pulsejet/mantle_radius, volume,
velocity, thrust, fluid_mass and /clock at publish_rate_hz, pulsejet/energy_ledger at ~5 Hz,
pulsejet/applied_command when the held command changes (and at ~5 Hz).
Subscribes pulsejet/cmd/pump_flow, pulsejet/cmd/valve, pulsejet/cmd/cable_force (std_msgs/Float64);
a non-finite or out-of-range value is rejected with a warning and the held command is kept.
Exit code: 0 on duration reached or SIGINT/SIGTERM, 1 after a physics blow-up, 2 on a bad scene
or parameter.
"""
from __future__ import annotations

import dataclasses
import math
import signal
import sys
import time

import rclpy
from rclpy.node import Node
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
from std_msgs.msg import Float64

from pulsejet_sim.models.base import Command, CommandError, SimulationBlowUp, check_command_value

#: command topics (relative names) -> Command field
COMMAND_TOPICS = {
    'pulsejet/cmd/pump_flow': 'pump_flow_m3_s',
    'pulsejet/cmd/valve': 'valve_opening',
    'pulsejet/cmd/cable_force': 'cable_force_n',
}
LEDGER_RATE_HZ = 5.0
DEFAULT_PUBLISH_RATE_HZ = 100.0
#: at most this many publication periods of physics are caught up in one tick; beyond, the
#: simulation falls behind (the wall-clock reference is moved) instead of stalling the node.
MAX_CATCH_UP_PERIODS = 5


def message_pairs(messages):
    """Accept what messages.py returns (a mapping topic -> msg or an iterable of (topic, msg))."""
    if messages is None:
        return []
    if hasattr(messages, 'items'):
        return list(messages.items())
    return list(messages)


def observation_is_finite(obs) -> bool:
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            return False
    return True


def check_number(name, value, low, high, allowed=None) -> float:
    """value (an int or float parameter) as float if finite and in [low, high]; else ValueError."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if ok:
        value = float(value)
        ok = math.isfinite(value) and low <= value <= high
    if not ok:
        raise ValueError(f'parameter {name}={value!r} rejected; allowed: {allowed or f"a number in [{low:g}, {high:g}]"}')
    return value


class Pacer:
    """Wall clock -> number of physics steps due, without drift.

    steps_due(now) = floor((now - t0) * rtf / dt) - steps_done, capped at max_steps per call; when
    the cap bites, t0 is moved forward so the lost time is not caught up later (no burst).
    """

    def __init__(self, dt_s: float, real_time_factor: float, max_steps: int, now: float):
        self.dt_s = dt_s
        self.rtf = real_time_factor
        self.max_steps = max(1, int(max_steps))
        self.t0 = now
        self.steps_done = 0
        self.dropped_s = 0.0   # wall seconds not simulated because the cap was hit

    def steps_due(self, now: float) -> int:
        target = int(math.floor((now - self.t0) * self.rtf / self.dt_s + 1e-9))
        due = target - self.steps_done
        if due > self.max_steps:
            lag_steps = due - self.max_steps
            shift = lag_steps * self.dt_s / self.rtf
            self.t0 += shift
            self.dropped_s += shift
            due = self.max_steps
        return max(0, due)

    def advance(self, n: int):
        self.steps_done += n


class SimNode(Node):

    def __init__(self, **kwargs):
        super().__init__('sim_node', **kwargs)
        # imported here: a broken scene or model then fails inside main() with one clear line
        from pulsejet_sim import messages
        from pulsejet_sim.scene import load_scene
        from pulsejet_sim.simulation import Simulation
        self._messages = messages

        self.declare_parameter('scene', 'pump_cycle', ParameterDescriptor(
            description='scene name under config/ or path to a scene YAML', read_only=True))
        # numbers accept integers too (`real_time_factor:=2`), so they are dynamically typed and
        # checked here, naming the value and the allowed range
        self.declare_parameter('real_time_factor', 1.0, ParameterDescriptor(
            description='simulated seconds per wall-clock second (> 0, at most 1000)', dynamic_typing=True))
        self.declare_parameter('publish_rate_hz', 0.0, ParameterDescriptor(
            description='publication rate in Hz (wall clock); 0 = the scene value or 100', read_only=True,
            dynamic_typing=True))
        self.declare_parameter('duration_s', 0.0, ParameterDescriptor(
            description='simulated seconds after which the node exits (0 = run forever)', read_only=True,
            dynamic_typing=True))
        self.declare_parameter('wait_for_subscribers', 0, ParameterDescriptor(
            description='hold the simulation at t=0 until /clock has this many subscribers', read_only=True,
            dynamic_typing=True))
        self.declare_parameter('wait_timeout_s', 10.0, ParameterDescriptor(
            description='wall seconds to wait for subscribers before starting anyway', read_only=True,
            dynamic_typing=True))

        self.scene = load_scene(self.get_parameter('scene').value)
        self.real_time_factor = self._number('real_time_factor', 1e-3, 1000.0)
        rate = self._number('publish_rate_hz', 0.0, 10000.0, '0 (scene value) or a rate in Hz up to 10000')
        if rate == 0.0:
            rate = float(getattr(self.scene, 'publish_rate_hz', 0.0) or DEFAULT_PUBLISH_RATE_HZ)
        self.publish_rate_hz = rate
        self.duration_s = self._number('duration_s', 0.0, 1e9, '0 (forever) or simulated seconds')
        self.wait_for_subscribers = int(self._number('wait_for_subscribers', 0, 100))
        self.wait_timeout_s = self._number('wait_timeout_s', 0.0, 3600.0)
        rtf = self.real_time_factor

        self.sim = Simulation(self.scene.model)
        self.dt_s = float(self.sim.model.dt_s)
        self.command = getattr(self.sim, 'default_command', None) or Command()
        self.done = False          # set when duration_s is reached (the node then exits)
        self.exit_code = 0
        self.halted = False        # set on SimulationBlowUp: no more stepping, no more publishing
        self._warm_up()

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._qos = qos
        self._pubs = {}
        # publishers up front (so subscribers can match before the first sample), others lazily
        for topic in tuple(getattr(messages, 'STATE_TOPICS', ())) + (
                'pulsejet/energy_ledger', getattr(messages, 'TOPIC_APPLIED_COMMAND', 'pulsejet/applied_command')):
            try:
                self._publisher_for(topic, messages.message_class(topic))
            except (AttributeError, ValueError):
                pass
        for topic, field in COMMAND_TOPICS.items():
            self.create_subscription(Float64, topic, self._command_callback(topic, field), qos)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.ticks = 0
        self._applied = None
        self._published_steps = -1
        self.ledger_every = max(1, int(round(rate / LEDGER_RATE_HZ)))
        self.pacer = None
        self.wait_started = time.monotonic()
        self.timer = self.create_timer(1.0 / rate, self._tick)
        self.get_logger().info(
            f'scene {self.scene.name!r} ({self.sim.model.name} model, dt {self.dt_s:g} s), '
            f'publishing at {rate:g} Hz, real-time factor {rtf:g}, '
            + (f'duration {self.duration_s:g} s' if self.duration_s > 0 else 'running until stopped'))

    # -- set-up ---------------------------------------------------------------------------------

    def _warm_up(self):
        """Run one step and reset, so that JIT compilation does not eat the first real-time period."""
        t = time.monotonic()
        try:
            self.sim.step(1, self.command)
            self.sim.energy_ledger()
        except SimulationBlowUp as exc:
            self.get_logger().error(f'physics blew up on the first step: {exc}')
        self.sim.reset()
        self.get_logger().debug(f'warm-up took {time.monotonic() - t:.2f} s')

    def _make_pacer(self, now):
        max_steps = max(1, int(math.ceil(MAX_CATCH_UP_PERIODS * self.real_time_factor
                                         / (self.publish_rate_hz * self.dt_s))))
        return Pacer(self.dt_s, self.real_time_factor, max_steps, now)

    def _publisher_for(self, topic, msg_type):
        pub = self._pubs.get(topic)
        if pub is None:
            pub = self.create_publisher(msg_type, topic, self._qos)
            self._pubs[topic] = pub
        return pub

    def _number(self, name, low, high, allowed=None):
        """A numeric parameter as float; ValueError naming the value and the allowed range."""
        return check_number(name, self.get_parameter(name).value, low, high, allowed)

    def _on_set_parameters(self, params):
        for p in params:
            if p.name == 'real_time_factor':
                try:
                    self.real_time_factor = check_number(p.name, p.value, 1e-3, 1000.0)
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
                if self.pacer is not None:   # re-base so the change does not create a jump
                    self.pacer = self._make_pacer(time.monotonic())
                self.get_logger().info(f'real-time factor set to {self.real_time_factor:g}')
        return SetParametersResult(successful=True)

    # -- commands -------------------------------------------------------------------------------

    def _command_callback(self, topic, field):
        low, high = Command.LIMITS[field]

        def callback(msg: Float64):
            try:
                value = check_command_value(field, msg.data, low, high)
            except CommandError as exc:
                self.get_logger().warning(f'{topic}: {exc}; command kept at {getattr(self.command, field)!r}')
                return
            self.command = dataclasses.replace(self.command, **{field: value})
        return callback

    # -- stepping -------------------------------------------------------------------------------

    def _tick(self):
        if self.done or self.halted:
            return
        now = time.monotonic()
        if self.pacer is None:
            if self.wait_for_subscribers > 0:
                have = self.count_subscribers('/clock')
                if have < self.wait_for_subscribers:
                    if now - self.wait_started < self.wait_timeout_s:
                        if self.ticks == 0:
                            self._publish(self.sim.observe())
                        self.ticks = 1
                        return
                    self.get_logger().warning(
                        f'only {have} of {self.wait_for_subscribers} /clock subscribers after '
                        f'{self.wait_timeout_s:g} s; starting anyway')
            self.pacer = self._make_pacer(now)
            self.started_wall = now
            self._publish_applied(self.command)
            self._publish(self.sim.observe(), ledger=True)
            return
        dropped = self.pacer.dropped_s
        n = self.pacer.steps_due(now)
        if self.pacer.dropped_s > dropped:
            wall = max(now - self.started_wall, 1e-9)
            self.get_logger().warning(
                f'the physics cannot keep up with real_time_factor {self.real_time_factor:g}: '
                f'{self.pacer.dropped_s:.2f} s of {wall:.2f} s wall time skipped so far '
                f'(achieved factor {self.sim.time_s / wall:.3g})', throttle_duration_sec=10.0)
        if self.duration_s > 0:
            remaining = int(round((self.duration_s - self.sim.time_s) / self.dt_s))
            n = min(n, max(0, remaining))
        if n > 0:
            command = self.command
            if command != self._applied or self.ticks % self.ledger_every == 0:
                self._publish_applied(command)
            try:
                obs = self.sim.step(n, command)
            except SimulationBlowUp as exc:
                self._halt(f'{exc}')
                return
            self.pacer.advance(n)
            if not observation_is_finite(obs):
                self._halt(f'non-finite observation at t={obs.time_s!r} s')
                return
            self.ticks += 1
            self._publish(obs, ledger=(self.ticks % self.ledger_every == 0))
        if self.duration_s > 0 and self.sim.time_s >= self.duration_s - 0.5 * self.dt_s:
            if self.sim.steps != self._published_steps:
                self._publish(self.sim.observe())
            self._publish_ledger(self.sim.time_s)
            lag = self.pacer.dropped_s
            self.get_logger().info(
                f'duration {self.duration_s:g} s of simulated time reached'
                + (f' ({lag:.3f} s of wall time could not be kept up with)' if lag > 0 else '')
                + '; exiting')
            self.done = True

    def _halt(self, cause):
        self.halted = True
        self.exit_code = 1
        self.get_logger().error(
            f'physics blew up: {cause}; stopped stepping at t={self.sim.time_s:.6f} s '
            f'(last good state kept, nothing more is published)')
        if self.duration_s > 0:
            self.done = True

    def _publish(self, obs, ledger=False):
        for topic, msg in message_pairs(self._messages.observation_messages(obs)):
            self._publisher_for(topic, type(msg)).publish(msg)
        self._published_steps = self.sim.steps
        if ledger:
            self._publish_ledger(obs.time_s)

    def _publish_ledger(self, time_s):
        ledger_values = self.sim.energy_ledger()
        if all(math.isfinite(v) for v in ledger_values.values()):
            msg = self._messages.ledger_message(ledger_values, time_s)
            self._publisher_for(getattr(self._messages, 'TOPIC_ENERGY_LEDGER', 'pulsejet/energy_ledger'),
                                type(msg)).publish(msg)

    def _publish_applied(self, command):
        """The command held from the current simulation time on (what a re-simulation replays);
        published when it changes and at the ledger rate."""
        self._applied = command
        make = getattr(self._messages, 'applied_command_message', None)
        if make is None:
            return
        msg = make(command, self.sim.time_s)
        self._publisher_for(getattr(self._messages, 'TOPIC_APPLIED_COMMAND', 'pulsejet/applied_command'),
                            type(msg)).publish(msg)


def main(args=None):
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    stop = {'signal': None}

    def on_signal(signum, _frame):
        stop['signal'] = signum

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    code = 0
    try:
        node = SimNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and stop['signal'] is None and not node.done:
            executor.spin_once(timeout_sec=0.05)
        code = node.exit_code
        if node.done:   # let the last samples reach reliable subscribers before the writers go away
            end = time.monotonic() + 0.3
            while rclpy.ok() and stop['signal'] is None and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
        if stop['signal'] is not None:
            node.get_logger().info(f'{signal.Signals(stop["signal"]).name} received at '
                                   f't={node.sim.time_s:.3f} s; shutting down')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, ParameterException) as exc:   # bad scene or parameter: one clear line
        print(f'sim_node: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    except Exception as exc:   # a bug: keep the traceback
        import traceback
        traceback.print_exc()
        print(f'sim_node: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
