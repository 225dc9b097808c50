"""ROS 2 node around `Simulation`: paces the physics, publishes every topic, serves pause/step/reset.

A thin adapter: the physics lives in `pulsejet_sim.simulation`, the message layout in
`pulsejet_sim.messages`. This module only paces, validates commands and parameters, publishes and
serves.

Parameters (see PARAMETERS below for the ranges; `ros2 param describe /sim_node <name>` shows them)
  scene                  (string, read-only)  scene name under config/ or a YAML path; default shell_robot
  scene_overrides        (string, read-only)  YAML mapping merged into the scene, e.g. '{material: {stiffness_n_m: 200}}'
  pacing                 (string, live)       real_time | as_fast_as_possible | lockstep
  real_time_factor       (double, live)       simulated s per wall s under real_time pacing; a change
                                              re-anchors the wall/sim reference (no clock jump)
  publish_rate_hz        (double, read-only)  publication rate (wall clock); 0 = scene value or 100
  duration_s             (double, read-only)  simulated time after which the node exits (0 = forever)
  wait_for_subscribers   (int, read-only)     hold the clock at 0 until `/clock` has this many
                                              subscribers (at most wait_timeout_s wall seconds)
  wait_timeout_s         (double, read-only)  see wait_for_subscribers; default 10
  start_paused           (bool, read-only)    start paused (resume with pulsejet/pause false)
  step_count             (int, live)          physics steps per pulsejet/step call; default 100
  watchdog_timeout_s     (double, live)       simulated s without an accepted command before the
                                              watchdog trips; 0 = off (default)
  watchdog_action        (string, live)       safe (pump off, valve open, cable released) | hold
  diagnostics_period_s   (double, read-only)  /diagnostics period in wall seconds; default 1

Publishes (stamped with simulation time, frame pulsejet/body): pulsejet/mantle_radius, volume,
velocity, thrust, fluid_mass, mantle_profile (models with a profile: shell) and /clock at publish_rate_hz (while paused or in lockstep the last
state and /clock are re-published every HOLD_REPUBLISH_S wall seconds, so late joiners see the
current time), pulsejet/energy_ledger at ~5 Hz, pulsejet/applied_command when the held command
changes (and at ~5 Hz), /diagnostics (diagnostic_msgs/DiagnosticArray) every diagnostics_period_s.
Subscribes pulsejet/cmd/pump_flow, pulsejet/cmd/valve, pulsejet/cmd/cable_force (std_msgs/Float64);
a non-finite or out-of-range value is rejected with a warning and the held command is kept.
Services (std_srvs): pulsejet/pause (SetBool), pulsejet/step (Trigger), pulsejet/reset (Trigger).
Reset returns to the scene's initial state *and* its initial command at simulation time 0: /clock
jumps back to 0 (like a Gazebo world reset); nodes with use_sim_time see a backward time jump.
The command watchdog measures the command age in *simulated* seconds (the same under any pacing,
pause or lockstep, and reproducible); when it trips it splits the physics batch at the deadline,
applies the safe command (or holds) from there (published on pulsejet/applied_command), logs a
warning and reports WARN on /diagnostics until the next accepted command.
Threads: a pacing thread ticks at publish_rate_hz on a drift-free wall-clock grid (sleeping between
ticks); the executor thread serves commands, services, parameters and /diagnostics. Both hold one
lock around the simulation, so a service never sees a half-done batch.
Exit code: 0 on duration reached or SIGINT/SIGTERM, 1 when stopped while the physics is stopped
after a blow-up (a reset clears it), 2 on a bad scene or parameter.
"""
from __future__ import annotations

import dataclasses
import math
import signal
import sys
import threading
import time

from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from pulsejet_sim.models.base import Command, CommandError, SimulationBlowUp, check_command_value
from pulsejet_sim import messages
from pulsejet_sim.node_params import ParamSpec, check_parameters
from pulsejet_sim.scene import DEFAULT_SCENE

#: command topics (relative names) -> Command field
COMMAND_TOPICS = {
    messages.TOPIC_CMD_PUMP_FLOW: 'pump_flow_m3_s',
    messages.TOPIC_CMD_VALVE: 'valve_opening',
    messages.TOPIC_CMD_CABLE_FORCE: 'cable_force_n',
}
SERVICE_PAUSE = 'pulsejet/pause'
SERVICE_STEP = 'pulsejet/step'
SERVICE_RESET = 'pulsejet/reset'
TOPIC_DIAGNOSTICS = '/diagnostics'
DIAGNOSTICS_NAME = 'pulsejet: sim_node'
PACING_MODES = ('real_time', 'as_fast_as_possible', 'lockstep')
WATCHDOG_ACTIONS = ('safe', 'hold')
#: what the watchdog applies with watchdog_action=safe: pump off, valve open, cable released
SAFE_COMMAND = Command(pump_flow_m3_s=0.0, valve_opening=1.0, cable_force_n=0.0)
LEDGER_RATE_HZ = 5.0
DEFAULT_PUBLISH_RATE_HZ = 100.0
HOLD_REPUBLISH_S = 0.5
#: at most this many publication periods of physics are caught up in one tick; beyond, the
#: simulation falls behind (the wall-clock reference is moved) instead of stalling the node.
MAX_CATCH_UP_PERIODS = 5
#: as_fast_as_possible: share of a timer period spent stepping before services/commands are served
AFAP_BUDGET = 0.8
#: diagnostics thresholds
RTF_WARN_FRACTION = 0.9       # achieved < 90 % of the requested factor (real_time, running) -> WARN
CLOSURE_WARN_RELATIVE = 0.05  # |energy closure| above 5 % -> WARN
STABLE_MARGIN_WARN = 1.0      # stable step / dt below 1 -> WARN (the step is above the stable estimate)


PARAMETERS = (
    ParamSpec('scene', DEFAULT_SCENE, 'scene name under config/ or path to a scene YAML', read_only=True,
              allowed='a scene name under config/ or a YAML file path'),
    ParamSpec('scene_overrides', '', 'YAML mapping merged into the scene section by section '
              '(e.g. "{material: {stiffness_n_m: 200}}"); empty = none', read_only=True,
              allowed='empty or a YAML mapping'),
    ParamSpec('pacing', 'real_time', 'how simulated time advances: real_time (scaled by real_time_factor), '
              'as_fast_as_possible, or lockstep (only through the pulsejet/step service)', choices=PACING_MODES),
    ParamSpec('real_time_factor', 1.0, 'simulated seconds per wall-clock second under real_time pacing',
              1e-3, 1000.0),
    ParamSpec('publish_rate_hz', 0.0, 'state publication rate in Hz (wall clock); 0 = the scene value or 100',
              0.0, 10000.0, read_only=True, allowed='0 (scene value) or a rate in [0, 10000] Hz'),
    ParamSpec('duration_s', 0.0, 'simulated seconds after which the node exits (0 = run forever)',
              0.0, 1e9, read_only=True),
    ParamSpec('wait_for_subscribers', 0, 'hold the simulation at t=0 until /clock has this many subscribers',
              0, 100, read_only=True),
    ParamSpec('wait_timeout_s', 10.0, 'wall seconds to wait for subscribers before starting anyway',
              0.0, 3600.0, read_only=True),
    ParamSpec('start_paused', False, 'start paused (resume with the pulsejet/pause service, data false)',
              read_only=True),
    ParamSpec('step_count', 100, 'physics steps advanced by one pulsejet/step call', 1, 10_000_000),
    ParamSpec('watchdog_timeout_s', 0.0, 'simulated seconds without an accepted command before the command '
              'watchdog trips (0 = off)', 0.0, 3600.0),
    ParamSpec('watchdog_action', 'safe', 'what the tripped watchdog does: safe = pump off, valve open, cable '
              'released; hold = keep the last command', choices=WATCHDOG_ACTIONS),
    ParamSpec('diagnostics_period_s', 1.0, 'period of /diagnostics in wall seconds', 0.05, 60.0, read_only=True),
)
PARAMETER_SPECS = {p.name: p for p in PARAMETERS}


def observation_is_finite(obs) -> bool:
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            return False
    return True


class Pacer:
    """Wall clock -> number of physics steps due, without drift.

    steps_due(now) = floor((now - t0) * rtf / dt) - steps_done, capped at max_steps per call; when
    the cap bites, t0 is moved forward so the lost time is not caught up later (no burst).
    A new Pacer (re-anchoring) starts from "now" and the current simulation time, so changing the
    factor, resuming or stepping never makes the clock jump.
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

    def lag_s(self, now: float) -> float:
        """Wall seconds the simulation is behind its schedule right now (>= 0)."""
        return max(0.0, (now - self.t0) - self.steps_done * self.dt_s / self.rtf)


class Window:
    """Counters over one diagnostics period."""

    def __init__(self, now: float, sim_time_s: float):
        self.wall0 = now
        self.sim0 = sim_time_s
        self.physics_ns = 0
        self.steps = 0
        self.free_running = True   # running under real_time pacing for the whole window


class SimNode(Node):

    def __init__(self, **kwargs):
        super().__init__('sim_node', **kwargs)
        # imported here: a broken scene or model then fails inside main() with one clear line
        import yaml
        from pulsejet_sim.scene import load_scene
        from pulsejet_sim.simulation import Simulation
        self._messages = messages
        self._ready = False
        # the pacing thread (ticks) and the executor thread (commands, services, parameters,
        # diagnostics) share the simulation under this lock
        self._lock = threading.RLock()
        self._stop_pacing = threading.Event()
        self._pacing_thread = None
        # validation of every value, at declaration (command-line overrides) and on live changes
        self.add_on_set_parameters_callback(self._on_set_parameters)
        for spec in PARAMETERS:
            self.declare_parameter(spec.name, spec.default, spec.descriptor())
        p = {spec.name: spec.check(self.get_parameter(spec.name).value) for spec in PARAMETERS}

        overrides = None
        if p['scene_overrides'].strip():
            try:
                overrides = yaml.safe_load(p['scene_overrides'])
            except yaml.YAMLError as exc:
                raise ValueError(f'parameter scene_overrides={p["scene_overrides"]!r} rejected: not YAML ({exc})') \
                    from None
            if not isinstance(overrides, dict):
                raise ValueError(f'parameter scene_overrides={p["scene_overrides"]!r} rejected; '
                                 f'allowed: empty or a YAML mapping')
        # command_driven: actuation a shell scene would drive from its built-in routine (the cable)
        # comes from pulsejet/cmd/* instead (controller_node sends the same routine)
        self.scene = load_scene(p['scene'], overrides=overrides, command_driven=True)
        self.pacing = p['pacing']
        self.real_time_factor = p['real_time_factor']
        rate = p['publish_rate_hz']
        if rate == 0.0:
            rate = float(getattr(self.scene, 'publish_rate_hz', 0.0) or DEFAULT_PUBLISH_RATE_HZ)
        self.publish_rate_hz = rate
        self.duration_s = p['duration_s']
        self.wait_for_subscribers = p['wait_for_subscribers']
        self.wait_timeout_s = p['wait_timeout_s']
        self.paused = p['start_paused']
        self.step_count = p['step_count']
        self.watchdog_timeout_s = p['watchdog_timeout_s']
        self.watchdog_action = p['watchdog_action']
        self.diagnostics_period_s = p['diagnostics_period_s']

        self.sim = Simulation(self.scene.model)
        self.dt_s = float(self.sim.model.dt_s)
        self.command = self.sim.command
        self.done = False          # set when duration_s is reached (the node then exits)
        self.exit_code = 0
        self.watchdog_tripped = False
        self._last_command_steps = 0      # simulation step of the last accepted command
        self._last_command_topic = None
        self._last_command_wall = None    # time.monotonic() of the last accepted command
        self._warm_up()

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._qos = qos
        self._pubs = {}
        # publishers up front (so subscribers can match before the first sample), others lazily.
        # /clock is reliable: compatible with the best-effort subscription of use_sim_time nodes.
        for topic in tuple(messages.STATE_TOPICS) + (messages.TOPIC_ENERGY_LEDGER, messages.TOPIC_APPLIED_COMMAND):
            self._publisher_for(topic, messages.message_class(topic))
        # the mantle profile, for models that have one (shell), with every state like the runner
        self.has_profile = self.sim.profile() is not None
        if self.has_profile:
            self._publisher_for(messages.TOPIC_MANTLE_PROFILE, messages.message_class(messages.TOPIC_MANTLE_PROFILE))
        from diagnostic_msgs.msg import DiagnosticArray
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, qos)
        for topic, field in COMMAND_TOPICS.items():
            self.create_subscription(Float64, topic, self._command_callback(topic, field), qos)
        self.create_service(SetBool, SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, SERVICE_STEP, self._on_step)
        self.create_service(Trigger, SERVICE_RESET, self._on_reset)

        self.ticks = 0
        self._applied = None
        self._published_steps = -1
        self._last_hold_publish = -math.inf
        self.ledger_every = max(1, int(round(rate / LEDGER_RATE_HZ)))
        self.afap_batch = max(1, int(round(1.0 / (rate * self.dt_s))))   # one publication period of sim time
        self.started = False
        self.pacer = None
        self._dropped_before_s = 0.0   # wall seconds skipped under earlier anchors
        self.wait_started = time.monotonic()
        self._window = Window(self.wait_started, 0.0)
        self.tick_period_s = 1.0 / rate
        self.diag_timer = self.create_timer(self.diagnostics_period_s, self._publish_diagnostics)
        self._ready = True
        self.get_logger().info(
            f'scene {self.scene.name!r} ({self.sim.model.name} model, dt {self.dt_s:g} s), '
            f'publishing at {rate:g} Hz, pacing {self.pacing}'
            + (f' x{self.real_time_factor:g}' if self.pacing == 'real_time' else '')
            + (', paused' if self.paused else '') + ', '
            + (f'duration {self.duration_s:g} s' if self.duration_s > 0 else 'running until stopped')
            + (f', watchdog {self.watchdog_timeout_s:g} s ({self.watchdog_action})' if self.watchdog_timeout_s > 0
               else ''))

    # -- set-up ---------------------------------------------------------------------------------

    def _warm_up(self):
        """Run one step and reset, so that JIT compilation does not eat the first real-time period."""
        t = time.monotonic()
        try:
            self.sim.step(1, self.command)
            self.sim.energy_ledger()
            self.sim.stable_step_s()
        except SimulationBlowUp as exc:
            self.get_logger().error(f'physics blew up on the first step: {exc}')
        self.sim.reset()
        self.get_logger().debug(f'warm-up took {time.monotonic() - t:.2f} s')

    def _reanchor(self, now=None):
        """New wall/sim reference from now on (after a factor or pacing change, a pause, step or reset)."""
        now = time.monotonic() if now is None else now
        if self.pacer is not None:
            self._dropped_before_s += self.pacer.dropped_s
        max_steps = max(1, int(math.ceil(MAX_CATCH_UP_PERIODS * self.real_time_factor
                                         / (self.publish_rate_hz * self.dt_s))))
        self.pacer = Pacer(self.dt_s, self.real_time_factor, max_steps, now)
        self._window.free_running = False

    def _publisher_for(self, topic, msg_type):
        pub = self._pubs.get(topic)
        if pub is None:
            pub = self.create_publisher(msg_type, topic, self._qos)
            self._pubs[topic] = pub
        return pub

    def _on_set_parameters(self, params):
        with self._lock:
            return self._set_parameters_locked(params)

    def _set_parameters_locked(self, params):
        checked, rejection = check_parameters(params, PARAMETER_SPECS)
        if rejection is not None:
            return rejection
        if not self._ready:   # declaration: values are read in __init__
            return SetParametersResult(successful=True)
        for name, value in checked.items():
            if name == 'real_time_factor' and value != self.real_time_factor:
                self.real_time_factor = value
                if self.pacer is not None:
                    self._reanchor()
                self.get_logger().info(f'real-time factor set to {value:g}')
            elif name == 'pacing' and value != self.pacing:
                self.pacing = value
                if self.pacer is not None:
                    self._reanchor()
                self.get_logger().info(f'pacing set to {value}')
            elif name == 'step_count':
                self.step_count = value
            elif name == 'watchdog_timeout_s':
                self.watchdog_timeout_s = value
                if value == 0.0:
                    self.watchdog_tripped = False
            elif name == 'watchdog_action':
                self.watchdog_action = value
        return SetParametersResult(successful=True)

    # -- commands -------------------------------------------------------------------------------

    def _command_callback(self, topic, field):
        low, high = Command.LIMITS[field]

        def callback(msg: Float64):
            with self._lock:
                accept(msg)

        def accept(msg: Float64):
            try:
                value = check_command_value(field, msg.data, low, high)
            except CommandError as exc:
                self.get_logger().warning(f'{topic}: {exc}; command kept at {getattr(self.command, field)!r}')
                return
            self.command = dataclasses.replace(self.command, **{field: value})
            self._last_command_steps = self.sim.steps
            self._last_command_topic = topic
            self._last_command_wall = time.monotonic()
            if self.watchdog_tripped:
                self.watchdog_tripped = False
                self.get_logger().info(f'command watchdog cleared by a command on {topic} at t={self.sim.time_s:.4f} s')
        return callback

    def command_age_s(self) -> float:
        """Simulated seconds since the last accepted command (or since the start/reset)."""
        return (self.sim.steps - self._last_command_steps) * self.dt_s

    def _watchdog_chunk(self, n: int) -> int:
        """Steps that may run before the watchdog deadline (tripping it when it is reached)."""
        if self.watchdog_timeout_s <= 0.0 or self.watchdog_tripped:
            return n
        limit = self._last_command_steps + max(1, int(math.ceil(self.watchdog_timeout_s / self.dt_s - 1e-9)))
        if self.sim.steps >= limit:
            self._trip_watchdog()
            return n
        return min(n, limit - self.sim.steps)

    def _trip_watchdog(self):
        self.watchdog_tripped = True
        if self.watchdog_action == 'safe':
            self.command = SAFE_COMMAND
            what = 'applying the safe command (pump off, valve open, cable released)'
        else:
            what = f'holding the last command {self.command}'
        self.get_logger().warning(
            f'command watchdog tripped at t={self.sim.time_s:.4f} s: no command for {self.command_age_s():.3f} s '
            f'of simulated time (timeout {self.watchdog_timeout_s:g} s); {what}')

    # -- services -------------------------------------------------------------------------------

    def _on_pause(self, request, response):
        with self._lock:
            return self._on_pause_locked(request, response)

    def _on_pause_locked(self, request, response):
        if request.data:
            response.message = ('already paused' if self.paused else 'paused') + f' at t={self.sim.time_s:.6f} s'
            self.paused = True
            self._window.free_running = False
            response.success = True
        elif self.pacing == 'lockstep':
            response.success = False
            response.message = ('not resumed: pacing is lockstep, simulated time advances only through '
                                f'{SERVICE_STEP}; set pacing to real_time or as_fast_as_possible to run freely')
        else:
            was = self.paused
            self.paused = False
            if self.pacer is not None:
                self._reanchor()
            response.success = True
            response.message = ('resumed' if was else 'already running') + f' at t={self.sim.time_s:.6f} s'
            if self.sim.fault is not None:
                response.message += f' (the physics is stopped after a fault; call {SERVICE_RESET})'
        return response

    def _on_step(self, request, response):
        with self._lock:
            return self._on_step_locked(request, response)

    def _on_step_locked(self, request, response):
        if self.sim.fault is not None:
            response.success = False
            response.message = f'refused: the physics is stopped after a fault ({self.sim.fault}); call {SERVICE_RESET}'
        elif self.done:
            response.success = False
            response.message = f'refused: duration_s={self.duration_s:g} s reached'
        elif self.pacing != 'lockstep' and not self.paused:
            response.success = False
            response.message = (f'refused: the simulation is running (pacing {self.pacing}); pause it with '
                                f'{SERVICE_PAUSE} first or set pacing to lockstep')
        else:
            if not self.started:
                self._start(time.monotonic(), publish=False)
            steps0 = self.sim.steps
            ok = self._run_steps(self.step_count)
            done = self.sim.steps - steps0
            if self.pacer is not None:
                self._reanchor()
            response.success = ok
            response.message = (f'advanced {done} steps to t={self.sim.time_s:.6f} s' if ok else
                                f'physics blew up after {done} steps: {self.sim.fault}')
        return response

    def _on_reset(self, request, response):
        with self._lock:
            return self._on_reset_locked(request, response)

    def _on_reset_locked(self, request, response):
        t_before = self.sim.time_s
        fault = self.sim.fault
        obs = self.sim.reset()
        self.command = self.sim.command
        self.exit_code = 0
        self.watchdog_tripped = False
        self._last_command_steps = 0
        self._applied = None
        self._window = Window(time.monotonic(), 0.0)
        self._window.free_running = False
        if self.started:
            self._reanchor()
        self._publish_applied(self.command)
        self._publish(obs, ledger=True)
        self.get_logger().info(f'reset at t={t_before:.6f} s' + (f' (clearing the fault: {fault})' if fault else '')
                               + '; simulation time back to 0')
        response.success = True
        response.message = (f'reset to the initial state of scene {self.scene.name!r}: simulation time back to 0 '
                            f'from t={t_before:.6f} s' + (', fault cleared' if fault else ''))
        return response

    # -- stepping -------------------------------------------------------------------------------

    def _start(self, now, publish=True):
        self.started = True
        self._reanchor(now)
        self.started_wall = now
        self._window = Window(now, self.sim.time_s)
        if publish:
            self._publish_applied(self.command)
            self._publish(self.sim.observe(), ledger=True)
            self._last_hold_publish = now

    # -- pacing thread --------------------------------------------------------------------------

    def start(self):
        self.start_pacing()

    def close(self):
        self.stop_pacing()

    def on_stop(self, signum):
        if signum is not None:
            self.get_logger().info(f'{signal.Signals(signum).name} received at t={self.sim.time_s:.3f} s; shutting down')

    def start_pacing(self):
        """Start the thread that ticks at publish_rate_hz on a drift-free wall-clock grid (sleeping
        between ticks, so the rate does not depend on the executor's wait-set overhead)."""
        if self._pacing_thread is None:
            self._pacing_thread = threading.Thread(target=self._pacing_loop, name='sim_node pacing', daemon=True)
            self._pacing_thread.start()

    def stop_pacing(self, timeout_s: float = 2.0):
        self._stop_pacing.set()
        if self._pacing_thread is not None:
            self._pacing_thread.join(timeout_s)

    def _pacing_loop(self):
        period = self.tick_period_s
        next_tick = time.monotonic()
        while not self._stop_pacing.is_set() and not self.done:
            try:
                with self._lock:
                    self._tick()
            except Exception as exc:   # a bug: report it, stop the node with a failure
                import traceback
                traceback.print_exc()
                self.get_logger().error(f'pacing thread stopped: {type(exc).__name__}: {exc}')
                self.exit_code = 2
                self.done = True
                return
            next_tick += period
            now = time.monotonic()
            if next_tick < now - period:   # more than a period late: restart the grid (no burst)
                next_tick = now
            delay = next_tick - now
            if delay > 0:
                self._stop_pacing.wait(delay) if delay > 0.002 else time.sleep(delay)

    def _tick(self):
        if self.done:
            return
        now = time.monotonic()
        if not self.started:
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
            self._start(now)
            return
        if self.sim.fault is not None:
            return
        if self.paused or self.pacing == 'lockstep':
            if now - self._last_hold_publish >= HOLD_REPUBLISH_S:
                self._publish(self.sim.observe())
                self._last_hold_publish = now
            return
        if self.pacing == 'as_fast_as_possible':
            budget_end = now + AFAP_BUDGET / self.publish_rate_hz
            while self._run_steps(self.afap_batch) and not self.done and time.monotonic() < budget_end:
                pass
            self.pacer.t0 = time.monotonic()   # keep the real-time anchor fresh for a switch back
            self.pacer.steps_done = 0
            return
        dropped = self.pacer.dropped_s
        n = self.pacer.steps_due(now)
        if self.pacer.dropped_s > dropped:
            wall = max(now - self.started_wall, 1e-9)
            self.get_logger().warning(
                f'the physics cannot keep up with real_time_factor {self.real_time_factor:g}: '
                f'{self._dropped_before_s + self.pacer.dropped_s:.2f} s of {wall:.2f} s wall time skipped so far',
                throttle_duration_sec=10.0)
        if n > 0:
            before = self.sim.steps
            self._run_steps(n)
            self.pacer.advance(self.sim.steps - before)
        elif self.duration_s > 0:
            self._check_duration()

    def _run_steps(self, n: int) -> bool:
        """Advance up to n steps (capped by duration_s) holding the command, splitting the batch at
        the watchdog deadline, then publish the state. False after a blow-up (the physics stops)."""
        if self.duration_s > 0:
            n = min(n, max(0, int(round((self.duration_s - self.sim.time_s) / self.dt_s))))
        obs = None
        remaining = n
        while remaining > 0:
            chunk = self._watchdog_chunk(remaining)
            command = self.command
            if command != self._applied or (obs is None and self.ticks % self.ledger_every == 0):
                self._publish_applied(command)
            t0 = time.perf_counter_ns()
            steps0 = self.sim.steps
            try:
                obs = self.sim.step(chunk, command)
            except SimulationBlowUp as exc:
                self._count_physics(t0, self.sim.steps - steps0)
                self._halt(str(exc))
                return False
            self._count_physics(t0, chunk)
            remaining -= chunk
            if not observation_is_finite(obs):
                self.sim.fault = f'non-finite observation at t={obs.time_s!r} s'
                self._halt(self.sim.fault)
                return False
        if obs is not None:
            self.ticks += 1
            self._publish(obs, ledger=(self.ticks % self.ledger_every == 0))
        self._check_duration()
        return True

    def _count_physics(self, t0_ns, steps):
        self._window.physics_ns += time.perf_counter_ns() - t0_ns
        self._window.steps += max(0, steps)

    def _check_duration(self):
        if self.duration_s > 0 and not self.done and self.sim.time_s >= self.duration_s - 0.5 * self.dt_s:
            if self.sim.steps != self._published_steps:
                self._publish(self.sim.observe())
            self._publish_ledger(self.sim.time_s)
            lag = self._dropped_before_s + (self.pacer.dropped_s if self.pacer else 0.0)
            self.get_logger().info(
                f'duration {self.duration_s:g} s of simulated time reached'
                + (f' ({lag:.3f} s of wall time could not be kept up with)' if lag > 0 else '')
                + '; exiting')
            self.done = True

    def _halt(self, cause):
        self.exit_code = 1
        self._window.free_running = False
        self.get_logger().error(
            f'physics blew up: {cause}; stopped stepping at t={self.sim.time_s:.6f} s '
            f'(last good state kept, nothing more is published; {SERVICE_RESET} restarts)')
        self._publish_diagnostics()
        if self.duration_s > 0:
            self.done = True

    # -- publishing -----------------------------------------------------------------------------

    def _publish(self, obs, ledger=False):
        if not observation_is_finite(obs):   # never publish NaN
            return
        if self.has_profile:   # before /clock, which the state's consumers take as its end
            profile = self.sim.profile()
            if profile is not None and all(math.isfinite(float(v)) for arr in profile for v in arr):
                msg = self._messages.profile_message(*profile, obs.time_s)
                self._publisher_for(self._messages.TOPIC_MANTLE_PROFILE, type(msg)).publish(msg)
        for topic, msg in self._messages.observation_messages(obs):
            self._publisher_for(topic, type(msg)).publish(msg)
        self._published_steps = self.sim.steps
        if ledger:
            self._publish_ledger(obs.time_s)

    def _publish_ledger(self, time_s):
        ledger_values = self.sim.energy_ledger()
        if all(math.isfinite(v) for v in ledger_values.values()):
            msg = self._messages.ledger_message(ledger_values, time_s)
            self._publisher_for(self._messages.TOPIC_ENERGY_LEDGER, type(msg)).publish(msg)

    def _publish_applied(self, command):
        """The command held from the current simulation time on (what a re-simulation replays);
        published when it changes and at the ledger rate."""
        self._applied = command
        msg = self._messages.applied_command_message(command, self.sim.time_s)
        self._publisher_for(self._messages.TOPIC_APPLIED_COMMAND, type(msg)).publish(msg)

    def run_state(self) -> str:
        if self.sim.fault is not None:
            return 'fault'
        if self.done:
            return 'done'
        if not self.started:
            return 'waiting'
        if self.pacing == 'lockstep':
            return 'lockstep'
        return 'paused' if self.paused else 'running'

    def diagnostics(self, now=None) -> tuple[int, str, dict]:
        """(level, message, key -> value) of the node's health over the last window (and resets it)."""
        from diagnostic_msgs.msg import DiagnosticStatus
        now = time.monotonic() if now is None else now
        w = self._window
        wall = max(now - w.wall0, 1e-9)
        achieved = (self.sim.time_s - w.sim0) / wall
        cost_us = (w.physics_ns / w.steps / 1e3) if w.steps else float('nan')
        state = self.run_state()
        lag = self.pacer.lag_s(now) if (self.pacer is not None and state == 'running'
                                         and self.pacing == 'real_time') else 0.0
        skipped = self._dropped_before_s + (self.pacer.dropped_s if self.pacer else 0.0)
        try:
            margin = float(self.sim.stable_step_s()) / self.dt_s
        except Exception:   # a model that cannot estimate it at this state
            margin = float('nan')
        ledger = self.sim.energy_ledger()
        closure = float(ledger.get('closure_relative', float('nan')))
        age = self.command_age_s()
        values = {
            'state': state, 'pacing': self.pacing,
            'real_time_factor_requested': self.real_time_factor,
            'real_time_factor_achieved': achieved,
            'physics_us_per_step': cost_us, 'steps_in_window': w.steps,
            'lag_s': lag, 'skipped_wall_s': skipped,
            'stable_step_margin': margin,
            'energy_closure_relative': closure,
            'command_age_s': age,
            'command_age_wall_s': (now - self._last_command_wall) if self._last_command_wall is not None
            else float('nan'),
            'watchdog': ('off' if self.watchdog_timeout_s <= 0 else
                         f'tripped ({self.watchdog_action})' if self.watchdog_tripped else 'armed'),
            'watchdog_timeout_s': self.watchdog_timeout_s,
            'time_s': self.sim.time_s, 'steps': self.sim.steps,
            'fault': self.sim.fault or '',
        }
        problems_warn = []
        if self.watchdog_tripped:
            problems_warn.append(f'command watchdog tripped: no command for {age:.3f} s (timeout '
                                 f'{self.watchdog_timeout_s:g} s), ' +
                                 ('safe command applied' if self.watchdog_action == 'safe' else 'last command held'))
        if math.isfinite(closure) and abs(closure) > CLOSURE_WARN_RELATIVE:
            problems_warn.append(f'energy closure {closure:+.2%} exceeds {CLOSURE_WARN_RELATIVE:.0%}')
        integrator = str(getattr(self.sim.model, 'integrator', 'explicit'))
        implicit = 'implicit' in integrator or 'backward' in integrator
        values['integrator'] = integrator
        if math.isfinite(margin) and margin < STABLE_MARGIN_WARN and not implicit:
            # an implicit integrator is not bound by the explicit stable step: reported, no warning
            problems_warn.append(f'step above the stable step (margin {margin:.3g})')
        if (w.free_running and state == 'running' and self.pacing == 'real_time' and wall > 0.5
                and achieved < RTF_WARN_FRACTION * self.real_time_factor):
            problems_warn.append(f'real-time factor {achieved:.3g} below the requested {self.real_time_factor:g}')
        if self.sim.fault is not None:
            level, message = DiagnosticStatus.ERROR, f'physics stopped: {self.sim.fault}'
        elif problems_warn:
            level, message = DiagnosticStatus.WARN, '; '.join(problems_warn)
        else:
            level = DiagnosticStatus.OK
            message = {'running': f'running ({self.pacing}'
                       + (f' x{self.real_time_factor:g}' if self.pacing == 'real_time' else '')
                       + f', achieved x{achieved:.3g})',
                       'paused': 'paused', 'lockstep': 'lockstep: waiting for step requests',
                       'waiting': 'waiting for subscribers', 'done': 'duration reached'}.get(state, state)
        self._window = Window(now, self.sim.time_s)
        self._window.free_running = state == 'running'
        return level, message, values

    def _publish_diagnostics(self):
        with self._lock:
            self._publish_diagnostics_locked()

    def _publish_diagnostics_locked(self):
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        level, message, values = self.diagnostics()
        status = DiagnosticStatus(level=level, name=DIAGNOSTICS_NAME, message=message,
                                  hardware_id=self._messages.LEDGER_HARDWARE_ID)
        status.values = [KeyValue(key=k, value=((repr(float(v)) if math.isfinite(v) else 'n/a')
                                                if isinstance(v, float) else str(v)))
                         for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self._messages.stamp(self.sim.time_s)
        msg.header.frame_id = self._messages.FRAME_ID
        msg.status = [status]
        self._diag_pub.publish(msg)


def main(args=None):
    from pulsejet_sim.node_main import run_node
    return run_node('sim_node', SimNode, args)


if __name__ == '__main__':
    sys.exit(main())
