"""ROS 2 node around a routine of `pulsejet_ctrl.routines`: reads simulation time from /clock,
publishes pump/valve/cable commands.

A thin adapter: the state machine lives in `pulsejet_ctrl.routines` (PumpValveRoutine, or
CableRoutine for a shell scene whose cable follows a routine: the scene is loaded command-driven,
so the simulator takes the cable force from here). The routine is evaluated at `rate_hz` in
*simulation* time (on /clock messages), so the command sequence does not depend on the
simulator's real-time factor beyond the clock's own resolution; when the time goes back (a
simulator reset) the routine restarts.

Parameters
  scene             (string, read-only)  scene whose `routine:` block gives the kind and defaults; default shell_robot
  rate_hz           (double, live)       command rate in simulated time, [0.001, 10000] Hz; default 50
  closed_loop       (bool, read-only)    answer every published state with one atomic command stamped
                                         at that state's time (sim_node's closed_loop pacing); default false
  routine fields    (read-only)          pump_valve: inflate_s, target_volume_m3, pump_flow_m3_s, hold_s,
                                         jet_s, valve_opening, start_delay_s (double), cycles (int);
                                         cable: amplitude_n, frequency_hz, contraction_s, release_s,
                                         start_delay_s. Default from the scene, each overridable at
                                         start-up; ranges from the routine's spec (`ros2 param describe`)
Every parameter has a descriptor (description, range); values are checked at declaration and on
live changes, a rejection names the value and the allowed range.
Subscribes /clock (rosgraph_msgs/Clock, best effort: a reliable or best-effort clock such as a bag
player's), pulsejet/volume (std_msgs/Float64, m^3), and with closed_loop pulsejet/velocity
(geometry_msgs/TwistStamped: each state's stamp).
Publishes pulsejet/cmd/pump_flow (m^3/s), pulsejet/cmd/valve (0..1), pulsejet/cmd/cable_force (N);
with closed_loop instead pulsejet/cmd/command (sensor_msgs/JointState, all actuators at once).
"""
from __future__ import annotations

import math
import sys

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from pulsejet_ctrl import routines as _routines
from pulsejet_sim import messages
from pulsejet_sim.node_params import ParamSpec, check_parameters
from pulsejet_sim.scene import DEFAULT_SCENE

#: routine field -> description (ranges and defaults come from the routine's spec)
ROUTINE_FIELDS = {
    'inflate_s': 's of pump inflation per cycle',
    'target_volume_m3': 'inflate until this cavity volume instead (0 = use inflate_s), m^3',
    'pump_flow_m3_s': 'pump flow while inflating, m^3/s',
    'hold_s': 's with pump off and valve shut before the jet',
    'jet_s': 's with the valve open (jetting)',
    'valve_opening': 'valve opening while jetting, 0..1',
    'cycles': 'number of cycles (0 = forever)',
    'start_delay_s': 's of simulated time before the first cycle',
    'amplitude_n': 'peak cable pull, N',
    'frequency_hz': 'cable pulls per second of simulated time, Hz',
    'contraction_s': 's of the half-cosine rise of the pull',
    'release_s': 's of the half-cosine release of the pull',
}
INTEGER_FIELDS = ('cycles',)
#: routine kind -> field -> pulsejet_sim.schema.Number (default, range)
ROUTINE_SPECS = {'pump_valve': _routines.PUMP_VALVE_SPEC, 'cable': _routines.CABLE_SPEC}


class ControllerNode(Node):

    def __init__(self, **kwargs):
        super().__init__('controller_node', **kwargs)
        from pulsejet_ctrl import routines
        from pulsejet_sim.scene import load_scene

        self._specs = {}
        self._ready = False
        # every value is checked here, at declaration (command-line overrides) and on live changes
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._declare(ParamSpec('scene', DEFAULT_SCENE, 'scene whose routine block gives the default parameters',
                                read_only=True, allowed='a scene name under config/ or a YAML file path'))
        self._declare(ParamSpec('rate_hz', 50.0, 'command rate in simulated time (Hz); live', 1e-3, 10000.0))
        self.closed_loop = bool(self._declare(ParamSpec(
            'closed_loop', False, 'answer every state with one atomic command stamped at its time '
            '(for sim_node pacing closed_loop)', read_only=True)))
        # command_driven: a shell scene's built-in cable routine becomes commands sent from here
        scene = load_scene(self.get_parameter('scene').value, command_driven=True)
        scene_routine = dict(getattr(scene, 'routine', None) or {})
        if not scene_routine:
            self.get_logger().warning(f'scene {scene.name!r} has no routine block: the routine defaults apply')
        kind = scene_routine.get('kind', 'pump_valve')
        if kind not in ROUTINE_SPECS:
            raise ValueError(f'scene {scene.name!r}: routine.kind={kind!r}; allowed: one of {", ".join(ROUTINE_SPECS)}')
        self._routine_cls = routines.ROUTINES[kind]
        config = dict(scene_routine, kind=kind)
        for name, number in ROUTINE_SPECS[kind].items():
            if name == 'kind':
                continue
            kind_of = int if name in INTEGER_FIELDS else float
            description = ROUTINE_FIELDS.get(name, f'{name} ({number.unit})')
            if number.low_open:
                description += f' (> {number.low:g})'
            low, high = number.low, number.high
            default = scene_routine.get(name, number.default)
            # numbers accept ints and floats (`inflate_s:=2`); the routine checks the values too.
            # Read-only: they define the routine's state machine (restart the node to change them).
            spec = ParamSpec(name, kind_of(default), description, low, high, read_only=True)
            config[name] = kind_of(self._declare(spec))
        self.config = config
        self.routine = self._routine_cls.from_config(dict(config))
        self.rate_hz = float(self.get_parameter('rate_hz').value)
        self.period_s = 1.0 / self.rate_hz
        self._ready = True

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._qos = qos
        self._pubs = {}
        if self.closed_loop:
            self._pubs[messages.TOPIC_CMD_COMMAND] = self.create_publisher(
                messages.message_class(messages.TOPIC_CMD_COMMAND), messages.TOPIC_CMD_COMMAND, qos)
        else:
            for topic in messages.COMMAND_TOPICS:
                self._pubs[topic] = self.create_publisher(Float64, topic, qos)
        self.volume_m3 = None
        self.last_time_s = None
        self.next_command_s = None
        self.commands_sent = 0
        self._answer = None   # (state time, command) of the last closed-loop answer
        self._volume_fresh = False   # a volume arrived since the last answer
        self._pending = None         # a state's time waiting for its volume
        best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        if self.closed_loop:
            self.create_subscription(messages.message_class(messages.TOPIC_VELOCITY), messages.TOPIC_VELOCITY,
                                     self._on_state, best_effort)
        else:
            self.create_subscription(Clock, messages.TOPIC_CLOCK, self._on_clock, best_effort)
        self.create_subscription(Float64, messages.TOPIC_VOLUME, self._on_volume, best_effort)
        self.get_logger().info(f'routine {config} at {self.rate_hz:g} Hz of simulated time; waiting for /clock')

    def _declare(self, spec: ParamSpec):
        self._specs[spec.name] = spec
        self.declare_parameter(spec.name, spec.default, spec.descriptor())
        return spec.check(self.get_parameter(spec.name).value)

    def _on_set_parameters(self, params):
        checked, rejection = check_parameters(params, self._specs)
        if rejection is not None:
            return rejection
        if self._ready and 'rate_hz' in checked:
            self.rate_hz = checked['rate_hz']
            self.period_s = 1.0 / self.rate_hz
            self.next_command_s = None     # next /clock sample sends and restarts the grid
            self.get_logger().info(f'command rate set to {self.rate_hz:g} Hz of simulated time')
        return SetParametersResult(successful=True)

    def _on_volume(self, msg: Float64):
        if math.isfinite(msg.data):
            self.volume_m3 = float(msg.data)
            self._volume_fresh = True
            if self._pending is not None:      # the state came first: answer it now
                t, self._pending = self._pending, None
                self._answer_state(t)

    def _on_state(self, msg):
        """Closed loop: answer this state once the volume of the same publication is in (the two
        topics may be taken in either order; the simulator publishes nothing else while it waits)."""
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self._volume_fresh:
            self._answer_state(t)
        else:
            self._pending = t

    def _answer_state(self, t):
        self._volume_fresh = False
        if self._answer is not None and t == self._answer[0]:
            cmd = self._answer[1]          # a repeated state: the same answer, the routine not stepped twice
        else:
            self._follow_time(t)
            cmd = self.routine.command(t, self.volume_m3)
            self._answer = (t, cmd)
        self._pubs[messages.TOPIC_CMD_COMMAND].publish(messages.command_message(cmd, t))
        self.commands_sent += 1

    def _follow_time(self, t):
        """Restart the routine when simulation time goes back (a simulator reset)."""
        if self.last_time_s is None:
            self.get_logger().info(f'first state at t={t:.3f} s')
        elif t < self.last_time_s - 1e-9:
            self.get_logger().warning(f'simulation time went back from {self.last_time_s:.3f} s to {t:.3f} s; '
                                      'restarting the routine')
            self.routine = self._routine_cls.from_config(dict(self.config))
            self.next_command_s = None
        self.last_time_s = t

    def _on_clock(self, msg: Clock):
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        self._follow_time(t)
        if self.next_command_s is not None and t < self.next_command_s - 1e-9:
            return
        self._send(t)
        # next command one period later, on the period grid (no drift)
        k = math.floor(t / self.period_s + 1e-9) + 1
        self.next_command_s = k * self.period_s

    def _send(self, t):
        cmd = self.routine.command(t, self.volume_m3)
        for topic, msg in messages.command_messages(cmd):
            pub = self._pubs.get(topic)
            if pub is None:
                pub = self._pubs[topic] = self.create_publisher(type(msg), topic, self._qos)
            pub.publish(msg)
        self.commands_sent += 1

    def on_stop(self, signum):
        self.get_logger().info(f'stopping after {self.commands_sent} commands')


def main(args=None):
    from pulsejet_sim.node_main import run_node
    return run_node('controller_node', ControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
