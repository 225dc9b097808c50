"""
ROS 2 node that runs a routine of `pulsejet_sim.routines` on the node's ROS clock.

It follows the node's ROS clock (simulation time from /clock through rclpy's time source,
`use_sim_time`) and publishes pump/valve/cable commands.

A thin adapter: the state machine lives in `pulsejet_sim.routines` (PumpValveRoutine, or
CableRoutine for a shell scene whose cable follows a routine: the scene is loaded command-driven,
so the simulator takes the cable force from here). The routine is evaluated at `rate_hz` of the
node's clock (`self.get_clock()`): with `use_sim_time` (the default here) that is *simulation*
time, so the command sequence does not depend on the simulator's real-time factor beyond the
clock's own resolution, and pause, lockstep steps and resets drive it. In simulated time the
commands are scheduled by the clock itself (a jump callback on every /clock update sends one when
the clock reaches the next period, as an rcl timer on that clock would), not by an rclpy timer: the
events executor this node spins (pulsejet_sim.ros.executor, a third of the CPU per message) waits
for a timer on simulated time in wall time and fires it in bursts when the clock does not run at
the wall rate. When the time goes back (a simulator reset, a restarted simulator, a looping replay)
the routine restarts and answers the new time at once. ROS time 0 means the simulation has not
started (or was reset and is held there): a /clock at 0 moves no clock, so while the clock reads 0
the routine's command for t = 0 is re-sent every STANDBY_PERIOD_S of wall time and the simulator
starts with it. With `-p use_sim_time:=false` the routine runs in wall time from the node's start.

ROS parameters
  scene             (string, read-only)  scene whose `routine:` block gives the kind and
                                         defaults; default shell_robot
  rate_hz           (double, live)       command rate in simulated time, [0.001, 10000] Hz;
                                         default 50
  closed_loop       (bool, read-only)    answer every published state with one atomic command
                                         stamped at that state's time (sim_node's closed_loop
                                         pacing); default false
  routine fields    (read-only)          pump_valve: inflate_s, target_volume_m3, pump_flow_m3_s,
                                         hold_s, jet_s, valve_opening, start_delay_s (double),
                                         cycles (int); cable: amplitude_n, frequency_hz,
                                         contraction_s, release_s, start_delay_s. Default from the
                                         scene, each overridable at start-up; ranges from the
                                         routine's spec (`ros2 param describe`)
  use_sim_time      (bool)               rclpy's own: follow /clock; default TRUE for this node
                                         (it is driven by sim_node; false with closed_loop, which
                                         runs on the state stamps); `-p use_sim_time:=false` =
                                         wall time
Every parameter has a descriptor (description, range); values are checked at declaration and on
live changes, a rejection names the value and the allowed range.
Subscribes /clock through rclpy's TimeSource (rosgraph_msgs/Clock, best effort depth 1: a reliable
or best-effort clock such as a bag player's), pulsejet/volume (std_msgs/Float64, m^3), and with
closed_loop pulsejet/velocity (geometry_msgs/TwistStamped: each state's stamp; in closed loop the
state stamps, not the clock, drive the routine).
Publishes pulsejet/cmd/pump_flow (m^3/s), pulsejet/cmd/valve (0..1), pulsejet/cmd/cable_force (N);
with closed_loop instead pulsejet/cmd/command (sensor_msgs/JointState, all actuators at once).
"""

from __future__ import annotations

import math
import sys

from pulsejet_sim.ros import messages
from pulsejet_sim.ros.controller_params import (  # noqa: F401 (ROUTINE_FIELDS: re-exported)
    INTEGER_FIELDS,
    NODE_PARAMETERS,
    ROUTINE_FIELDS,
    routine_parameters,
    ROUTINE_SPECS,
)
from pulsejet_sim.ros.node_params import check_parameters, declare, ParamSpec
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockChange, JumpThreshold
from rclpy.clock_type import ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

#: wall seconds between re-sends of the t = 0 command while the ROS clock reads 0 (not started)
STANDBY_PERIOD_S = 0.2
USE_SIM_TIME = 'use_sim_time'


class ControllerNode(Node):

    def __init__(self, **kwargs):
        super().__init__('controller_node', **kwargs)
        from pulsejet_sim import routines
        from pulsejet_sim.scene import load_scene

        self._specs = {}
        self._ready = False
        # every value is checked here, at declaration (command-line overrides) and on live changes
        self.add_on_set_parameters_callback(self._on_set_parameters)
        scene_spec, rate_spec, closed_loop_spec = NODE_PARAMETERS
        self._declare(scene_spec)
        self._declare(rate_spec)
        self.closed_loop = bool(self._declare(closed_loop_spec))
        # use_sim_time defaults to true here, except with closed_loop (the state stamps drive the
        # routine there: no /clock subscription, as before). rclpy's TimeSource declared it
        # (default false) in Node.__init__; constructor parameter_overrides would beat the command
        # line, so the default is applied only when neither the command line, a params file nor the
        # caller's parameter_overrides gave a value (-p use_sim_time:=false still means wall time).
        if USE_SIM_TIME not in self._parameter_overrides and not self.closed_loop:
            result = self.set_parameters([Parameter(USE_SIM_TIME, Parameter.Type.BOOL, True)])[0]
            if not result.successful:
                raise ValueError(f'parameter {USE_SIM_TIME}=True rejected: {result.reason}')
        # command_driven: a shell scene's built-in cable routine becomes commands sent from here
        scene = load_scene(self.get_parameter('scene').value, command_driven=True)
        scene_routine = dict(getattr(scene, 'routine', None) or {})
        if not scene_routine:
            self.get_logger().warning(
                f'scene {scene.name!r} has no routine block: the routine defaults apply'
            )
        kind = scene_routine.get('kind', 'pump_valve')
        if kind not in ROUTINE_SPECS:
            raise ValueError(
                f'scene {scene.name!r}: routine.kind={kind!r}; allowed: one of'
                f' {", ".join(ROUTINE_SPECS)}'
            )
        self._routine_cls = routines.ROUTINES[kind]
        config = dict(scene_routine, kind=kind)
        for spec in routine_parameters(kind, scene_routine):
            value = self._declare(spec)
            config[spec.name] = int(value) if spec.name in INTEGER_FIELDS else value
        self.config = config
        self.routine = self._routine_cls.from_config(dict(config))
        self.rate_hz = float(self.get_parameter('rate_hz').value)
        self.period_s = 1.0 / self.rate_hz
        self._ready = True

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )
        self._qos = qos
        self._pubs = {}
        if self.closed_loop:
            self._pubs[messages.TOPIC_CMD_COMMAND] = self.create_publisher(
                messages.message_class(messages.TOPIC_CMD_COMMAND), messages.TOPIC_CMD_COMMAND, qos
            )
        else:
            for topic in messages.COMMAND_TOPICS:
                self._pubs[topic] = self.create_publisher(Float64, topic, qos)
        self.volume_m3 = None
        self.last_time_s = None
        self.commands_sent = 0
        self._answer = None  # (state time, command) of the last closed-loop answer
        self._volume_fresh = False  # a volume arrived since the last answer
        self._pending = None  # a state's time waiting for its volume
        best_effort = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT
        )
        self._timer = None
        clock = self.get_clock()
        # routine time = clock time - origin: 0 for ROS (simulation) time, the start for wall time
        self._origin_ns = 0 if clock.ros_time_is_active else clock.now().nanoseconds
        if self.closed_loop:
            self.create_subscription(
                messages.message_class(messages.TOPIC_VELOCITY),
                messages.TOPIC_VELOCITY,
                self._on_state,
                best_effort,
            )
        else:
            # wall time (use_sim_time false): an rclpy timer on the node clock; in simulated time
            # the clock's own updates schedule the commands (_on_time_jump), on the grid
            # k / rate_hz of simulated time from the clock's start at 0
            self._timer = self.create_timer(self.period_s, self._on_timer)
            self._next_due_ns = self._period_ns()
            if clock.ros_time_is_active:
                self._timer.cancel()
            # every /clock update (forward and back: reset, restarted simulator, looping replay)
            # and use_sim_time switches
            self._jump_handle = clock.create_jump_callback(
                JumpThreshold(
                    min_forward=Duration(nanoseconds=1),
                    min_backward=Duration(nanoseconds=-1),
                    on_clock_change=True,
                ),
                post_callback=self._on_time_jump,
            )
            self.create_timer(
                STANDBY_PERIOD_S, self._on_standby, clock=Clock(clock_type=ClockType.STEADY_TIME)
            )
        self.create_subscription(Float64, messages.TOPIC_VOLUME, self._on_volume, best_effort)
        timing = (
            'simulated time (use_sim_time: /clock); waiting for /clock'
            if clock.ros_time_is_active
            else 'wall time from now (use_sim_time false)'
        )
        self.get_logger().info(f'routine {config} at {self.rate_hz:g} Hz of {timing}')

    def _declare(self, spec: ParamSpec):
        self._specs[spec.name] = spec
        return declare(self, spec)

    def _on_set_parameters(self, params):
        checked, rejection = check_parameters(params, self._specs)
        if rejection is not None:
            return rejection
        if self._ready and 'rate_hz' in checked:
            self.rate_hz = checked['rate_hz']
            self.period_s = 1.0 / self.rate_hz
            if self._timer is not None:  # the new period from now on (not after the old one)
                self._timer.timer_period_ns = self._period_ns()
                if self.get_clock().ros_time_is_active:
                    self._next_due_ns = self.get_clock().now().nanoseconds + self._period_ns()
                else:
                    self._timer.reset()
            self.get_logger().info(f'command rate set to {self.rate_hz:g} Hz of the node clock')
        return SetParametersResult(successful=True)

    def _on_volume(self, msg: Float64):
        if math.isfinite(msg.data):
            self.volume_m3 = float(msg.data)
            self._volume_fresh = True
            if self._pending is not None:  # the state came first: answer it now
                t, self._pending = self._pending, None
                self._answer_state(t)

    def _on_state(self, msg):
        """
        Answer this state (closed loop) once the volume of the same publication is in.

        The two topics may be taken in either order; the simulator publishes nothing else
        while it waits.
        """
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self._volume_fresh:
            self._answer_state(t)
        else:
            self._pending = t

    def _answer_state(self, t):
        self._volume_fresh = False
        if self._answer is not None and t == self._answer[0]:
            cmd = self._answer[
                1
            ]  # a repeated state: the same answer, the routine not stepped twice
        else:
            self._follow_time(t)
            cmd = self.routine.command(t, self.volume_m3)
            self._answer = (t, cmd)
        self._pubs[messages.TOPIC_CMD_COMMAND].publish(messages.command_message(cmd, t))
        self.commands_sent += 1

    def _follow_time(self, t):
        """Restart the routine when the time goes back (a simulator reset)."""
        if self.last_time_s is None:
            self.get_logger().info(f'first state at t={t:.3f} s')
        elif t < self.last_time_s - 1e-9:
            self.get_logger().warning(
                f'simulation time went back from {self.last_time_s:.3f} s to {t:.3f} s; '
                'restarting the routine'
            )
            self.routine = self._routine_cls.from_config(dict(self.config))
        self.last_time_s = t

    def _routine_time(self) -> float:
        return (self.get_clock().now().nanoseconds - self._origin_ns) * 1e-9

    def _on_timer(self):
        """One command per period of the node clock (a jump over several periods sends one)."""
        t = self._routine_time()
        self._follow_time(t)  # also catches a wall clock stepped back (no jump callback for that)
        self._send(t)

    def _period_ns(self) -> int:
        return int(round(self.period_s * 1e9))

    def _on_time_jump(self, jump):
        """Post-jump callback of the node clock (runs where /clock is taken, in the executor)."""
        clock = self.get_clock()
        if jump.clock_change in (ClockChange.ROS_TIME_ACTIVATED, ClockChange.ROS_TIME_DEACTIVATED):
            # use_sim_time switched live: a new time base, the routine starts over on it
            self._origin_ns = 0 if clock.ros_time_is_active else clock.now().nanoseconds
            self.routine = self._routine_cls.from_config(dict(self.config))
            self.last_time_s = None
            self.get_logger().info(
                f'use_sim_time now {clock.ros_time_is_active}: restarting the routine'
            )
            if clock.ros_time_is_active:
                self._timer.cancel()
                self._next_due_ns = clock.now().nanoseconds + self._period_ns()
            else:
                self._timer.reset()
            return
        if not clock.ros_time_is_active:  # the system clock stepped: the wall timer goes on
            return
        now_ns = clock.now().nanoseconds
        if jump.delta.nanoseconds < 0:  # back: the routine restarts and answers the new time
            t = self._routine_time()
            self._follow_time(t)
            self._send(t)
            self._next_due_ns = now_ns + self._period_ns()  # one period after the new time
            return
        if now_ns < self._next_due_ns:
            return
        # one command however many periods the clock passed, then the next point of the grid
        self._on_timer()
        period = self._period_ns()
        self._next_due_ns += period * ((now_ns - self._next_due_ns) // period + 1)

    def _on_standby(self):
        """
        Re-send the command for t = 0 while the ROS clock reads 0.

        While the ROS clock reads 0 (no /clock yet, or a simulator held at its start) re-send
        the command for t = 0: a /clock at 0 moves no clock, so no timer or jump would answer it.
        """
        clock = self.get_clock()
        if clock.ros_time_is_active and clock.now().nanoseconds == 0:
            self._send(0.0)

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
    from pulsejet_sim.ros.node_main import run_node

    return run_node('controller_node', ControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
