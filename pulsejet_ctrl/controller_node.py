"""ROS 2 node around `PumpValveRoutine`: reads simulation time from /clock, publishes pump/valve commands.

A thin adapter: the state machine lives in `pulsejet_ctrl.routines`. The routine is evaluated at
`rate_hz` in *simulation* time (on /clock messages), so the command sequence does not depend on
the simulator's real-time factor beyond the clock's own resolution.

Parameters
  scene             (string, read-only)  scene whose `routine:` block gives the defaults; default pump_cycle
  rate_hz           (double > 0)         command rate in simulated time; default 50
  inflate_s, target_volume_m3, pump_flow_m3_s, hold_s, jet_s, valve_opening, start_delay_s (double),
  cycles (int)                           routine fields, default from the scene, each overridable
Subscribes /clock (rosgraph_msgs/Clock), pulsejet/volume (std_msgs/Float64, m^3).
Publishes pulsejet/cmd/pump_flow (m^3/s), pulsejet/cmd/valve (0..1), pulsejet/cmd/cable_force (N, 0).
"""
from __future__ import annotations

import dataclasses
import math
import signal
import sys

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

ROUTINE_FIELDS = {
    'inflate_s': (float, 's of pump inflation per cycle'),
    'target_volume_m3': (float, 'inflate until this cavity volume instead (0 = use inflate_s)'),
    'pump_flow_m3_s': (float, 'pump flow while inflating, m^3/s'),
    'hold_s': (float, 's with pump off and valve shut before the jet'),
    'jet_s': (float, 's with the valve open (jetting)'),
    'valve_opening': (float, 'valve opening while jetting, 0..1'),
    'cycles': (int, 'number of cycles (0 = forever)'),
    'start_delay_s': (float, 's of simulated time before the first cycle'),
}


def message_pairs(messages):
    if messages is None:
        return []
    if hasattr(messages, 'items'):
        return list(messages.items())
    return list(messages)


class ControllerNode(Node):

    def __init__(self, **kwargs):
        super().__init__('controller_node', **kwargs)
        from pulsejet_ctrl.routines import PumpValveRoutine
        from pulsejet_sim import messages
        from pulsejet_sim.scene import load_scene
        self._messages = messages
        self._routine_cls = PumpValveRoutine

        self.declare_parameter('scene', 'pump_cycle', ParameterDescriptor(
            description='scene whose routine block gives the default parameters', read_only=True))
        self.declare_parameter('rate_hz', 50.0, ParameterDescriptor(
            description='command rate in simulated time (Hz, > 0)', read_only=True, dynamic_typing=True))
        scene = load_scene(self.get_parameter('scene').value)
        scene_routine = dict(getattr(scene, 'routine', None) or {})
        if not scene_routine:
            self.get_logger().warning(f'scene {scene.name!r} has no routine block: the routine defaults apply')
        defaults = {f.name: f.default for f in dataclasses.fields(PumpValveRoutine)}
        config = dict(scene_routine)
        for name, (kind, description) in ROUTINE_FIELDS.items():
            default = scene_routine.get(name, defaults.get(name))
            # numbers accept ints and floats (`inflate_s:=2`); the routine checks the values
            descriptor = ParameterDescriptor(description=description, read_only=True, dynamic_typing=True)
            value = self.declare_parameter(name, kind(default), descriptor).value
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    (kind is int and not float(value).is_integer()):
                allowed = 'a whole number' if kind is int else 'a number'
                raise ValueError(f'parameter {name}={value!r} rejected; allowed: {allowed} ({description})')
            config[name] = kind(value)
        self.config = config
        self.routine = PumpValveRoutine.from_config(dict(config))

        rate = self.get_parameter('rate_hz').value
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise ValueError(f'parameter rate_hz={rate!r} rejected; allowed: a finite number > 0')
        self.rate_hz = float(rate)
        self.period_s = 1.0 / self.rate_hz

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._qos = qos
        self._pubs = {}
        for topic in ('pulsejet/cmd/pump_flow', 'pulsejet/cmd/valve', 'pulsejet/cmd/cable_force'):
            self._pubs[topic] = self.create_publisher(Float64, topic, qos)
        self.volume_m3 = None
        self.last_time_s = None
        self.next_command_s = None
        self.commands_sent = 0
        self.create_subscription(Clock, '/clock', self._on_clock, qos)
        self.create_subscription(Float64, 'pulsejet/volume', self._on_volume, qos)
        self.get_logger().info(f'routine {config} at {self.rate_hz:g} Hz of simulated time; waiting for /clock')

    def _on_volume(self, msg: Float64):
        if math.isfinite(msg.data):
            self.volume_m3 = float(msg.data)

    def _on_clock(self, msg: Clock):
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        if self.last_time_s is None:
            self.get_logger().info(f'first /clock at t={t:.3f} s')
        elif t < self.last_time_s - 1e-9:
            self.get_logger().warning(f'simulation time went back from {self.last_time_s:.3f} s to {t:.3f} s; '
                                      'restarting the routine')
            self.routine = self._routine_cls.from_config(dict(self.config))
            self.next_command_s = None
        self.last_time_s = t
        if self.next_command_s is not None and t < self.next_command_s - 1e-9:
            return
        self._send(t)
        # next command one period later, on the period grid (no drift)
        k = math.floor(t / self.period_s + 1e-9) + 1
        self.next_command_s = k * self.period_s

    def _send(self, t):
        cmd = self.routine.command(t, self.volume_m3)
        cmd = type(cmd)(cmd.pump_flow_m3_s, cmd.valve_opening, 0.0) if cmd.cable_force_n != 0.0 else cmd
        for topic, msg in message_pairs(self._messages.command_messages(cmd)):
            pub = self._pubs.get(topic)
            if pub is None:
                pub = self._pubs[topic] = self.create_publisher(type(msg), topic, self._qos)
            pub.publish(msg)
        self.commands_sent += 1


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
        node = ControllerNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and stop['signal'] is None:
            executor.spin_once(timeout_sec=0.05)
        node.get_logger().info(f'stopping after {node.commands_sent} commands')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, ParameterException) as exc:   # bad scene or parameter: one clear line
        print(f'controller_node: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    except Exception as exc:   # a bug: keep the traceback
        import traceback
        traceback.print_exc()
        print(f'controller_node: error: {type(exc).__name__}: {exc}', file=sys.stderr, flush=True)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
