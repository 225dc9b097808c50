"""
ROS 2 node around the ROS-free engine `pulsejet_sim.engine.session.Session`.

Parameters, topics, services and /diagnostics; the session paces the physics and says what to
publish.

Parameters (see PARAMETERS for the ranges; `ros2 param describe /sim_node <name>` shows them)
  scene                 (string, read-only)  scene name under config/ or a YAML path; default
                                             shell_robot
  scene_overrides       (string, read-only)  YAML mapping merged into the scene (kept for
                                             compatibility)
  scene.<section>.<key> (any, read-only)     one scene key each, merged over scene_overrides, e.g.
                                             `-p scene.geometry.nozzle_radius_m:=0.01`, or a nested
                                             `scene:` mapping in a params file (rcl flattens it)
  pacing                (string, live)       real_time | as_fast_as_possible | lockstep |
                                             closed_loop
  real_time_factor      (double, live)       simulated s per wall s under real_time pacing
  publish_rate_hz       (double, read-only)  publication rate; 0 = scene value or 100. Every state
                                             lies on the physics step's grid, one publication
                                             period apart
  control_period_s      (double, read-only)  closed_loop: simulated s per control period (0 = one
                                             publication period)
  lookahead_s           (double, read-only)  real_time: simulated s the physics runs ahead; each
                                             state is sent at its own wall time, so slow steps do
                                             not jitter publication (default 0)
  duration_s            (double, read-only)  simulated time after which the node exits (0 =
                                             forever)
  wait_for_subscribers  (int, read-only)     hold the clock at 0 until `/clock` has this many
                                             subscribers
  wait_timeout_s        (double, read-only)  see wait_for_subscribers; default 10
  start_paused          (bool, read-only)    start paused (resume with pulsejet/pause false)
  step_count            (int, live)          physics steps per pulsejet/step call; default 100
  watchdog_timeout_s    (double, live)       command age before the watchdog trips; 0 = off
                                             (default)
  watchdog_clock        (string, live)       sim (simulated seconds, reproducible) | wall (wall
                                             seconds)
  watchdog_action       (string, live)       safe (pump off, valve open, cable released) | hold
  diagnostics_period_s  (double, read-only)  /diagnostics period in wall seconds; default 1
  odom_frame_id         (string, read-only)  header frame of `odom` (nav_msgs/Odometry); default
                                             odom
  base_frame_id         (string, read-only)  child frame of `odom`; default base_link

Topic, service and status names: `pulsejet_sim.interface` (one place for every name). Commands
arrive per actuator (std_msgs/Float64) or atomically on pulsejet/cmd/command
(sensor_msgs/JointState, every named actuator at the same step); subscriptions are best effort, so
reliable and best-effort publishers both connect. A non-finite or out-of-range value is rejected
with a warning naming it (throttled; /diagnostics counts every one); the held command is kept.
Commands reach the pacing thread through an inbox, so the executor never waits for a physics batch;
the kernels release the GIL while they step. Reset returns to the scene's initial state and command
at time 0 (/clock jumps back, like a Gazebo world reset). The diagnostic status is named after the
node's fully qualified name, so two robots in one domain stay apart.
Exit code: 0 on duration reached or SIGINT/SIGTERM, 1 when stopped after a blow-up, 2 on a bad
scene or parameter.
"""

from __future__ import annotations

import collections
import functools
import math
import signal
import sys
import threading
import time

import numpy as np
from pulsejet_sim.engine import session as eng
from pulsejet_sim.engine.outbox import TimedOutbox
from pulsejet_sim.models.base import CommandError, SimulationBlowUp
from pulsejet_sim.ros import messages
from pulsejet_sim.ros.node_params import (
    check_parameters,
    ParamSpec,
    scene_override_descriptor,
    scene_override_names,
    scene_overrides,
)
from pulsejet_sim.scene import DEFAULT_SCENE
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

DEFAULT_PUBLISH_RATE_HZ = 100.0
PARAMETERS = (
    ParamSpec(
        'scene',
        DEFAULT_SCENE,
        'scene name under config/ or path to a scene YAML',
        read_only=True,
        allowed='a scene name under config/ or a YAML file path',
    ),
    ParamSpec(
        'scene_overrides',
        '',
        'YAML mapping merged into the scene section by section '
        '(e.g. "{material: {stiffness_n_m: 200}}"); empty = none',
        read_only=True,
        allowed='empty or a YAML mapping',
    ),
    ParamSpec(
        'pacing',
        'real_time',
        'how simulated time advances: real_time (scaled by real_time_factor), '
        'as_fast_as_possible, lockstep (only through the pulsejet/step service) or closed_loop '
        '(one control '
        'period per command that answers the last state)',
        choices=eng.PACING_MODES,
    ),
    ParamSpec(
        'real_time_factor',
        1.0,
        'simulated seconds per wall-clock second under real_time pacing',
        1e-3,
        1000.0,
    ),
    ParamSpec(
        'publish_rate_hz',
        0.0,
        'state publication rate in Hz; 0 = the scene value or 100',
        0.0,
        10000.0,
        read_only=True,
        allowed='0 (scene value) or a rate in [0, 10000] Hz',
    ),
    ParamSpec(
        'control_period_s',
        0.0,
        'closed_loop pacing: simulated seconds per control period ' '(0 = one publication period)',
        0.0,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        'lookahead_s',
        0.0,
        'real_time pacing: simulated seconds the physics runs ahead of publication, so '
        'slow steps do not delay states (each is published at its wall time); commands act that '
        'much '
        'later (0 = publish each state as soon as it is computed)',
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        'duration_s',
        0.0,
        'simulated seconds after which the node exits (0 = run forever)',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_subscribers',
        0,
        'hold the simulation at t=0 until /clock has this many subscribers',
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        'wait_timeout_s',
        10.0,
        'wall seconds to wait for subscribers before starting anyway',
        0.0,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        'start_paused',
        False,
        'start paused (resume with the pulsejet/pause service, data false)',
        read_only=True,
    ),
    ParamSpec(
        'step_count', 100, 'physics steps advanced by one pulsejet/step call', 1, 10_000_000
    ),
    ParamSpec(
        'watchdog_timeout_s',
        0.0,
        'command age before the command watchdog trips (0 = off)',
        0.0,
        3600.0,
    ),
    ParamSpec(
        'watchdog_clock',
        'sim',
        'what the watchdog measures the command age in: sim (simulated '
        'seconds) or wall (wall-clock seconds)',
        choices=eng.WATCHDOG_CLOCKS,
    ),
    ParamSpec(
        'watchdog_action',
        'safe',
        'what the tripped watchdog does: safe = pump off, valve open, cable '
        'released; hold = keep the last command',
        choices=eng.WATCHDOG_ACTIONS,
    ),
    ParamSpec(
        'diagnostics_period_s',
        1.0,
        'period of /diagnostics in wall seconds',
        0.05,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        'odom_frame_id',
        messages.ODOM_FRAME_ID,
        'frame of the odometry pose (REP 105)',
        read_only=True,
        allowed='a frame name',
    ),
    ParamSpec(
        'base_frame_id',
        messages.BASE_FRAME_ID,
        'body frame of the odometry twist (REP 105)',
        read_only=True,
        allowed='a frame name',
    ),
)
PARAMETER_SPECS = {p.name: p for p in PARAMETERS}
LIVE_CONFIG = (
    'pacing',
    'real_time_factor',
    'step_count',
    'watchdog_timeout_s',
    'watchdog_clock',
    'watchdog_action',
)
GIL_SWITCH_INTERVAL_S = 2e-4
PROFILE_RATE_MAX_HZ = 100.0
#: command-rejection warnings: a burst of this many, then this many per second; the rest are only
#: counted (commands_rejected in /diagnostics) and summed up in the next warning
REJECTION_LOG_BURST = 10
REJECTION_LOG_RATE_HZ = 2.0


class SimNode(Node):

    def __init__(self, **kwargs):
        super().__init__('sim_node', **kwargs)
        from pulsejet_sim.models.schema import safe_load_yaml, YAMLInputError
        from pulsejet_sim.scene import load_scene
        from pulsejet_sim.simulation import Simulation
        import yaml

        self._ready = False
        # the pacing thread and the executor thread (commands, services, parameters, diagnostics)
        # share the session under this lock
        self._lock = threading.RLock()
        self._stop_pacing = threading.Event()
        # commands go through this inbox instead of the lock: the executor never waits for a
        # physics batch to hand one over (the pacing thread applies them, in arrival order, before
        # it steps)
        self._inbox = collections.deque()
        self._wake = threading.Event()
        self._outbox = TimedOutbox(
            name='sim_node publication'
        )  # states computed ahead (lookahead_s)
        self._outbox_due = None  # wall time of the last batch put there
        self._pacing_thread = None
        self._warn_tokens, self._warn_refilled, self._warn_suppressed = (
            float(REJECTION_LOG_BURST),
            0.0,
            0,
        )
        self._finished = False
        self.add_on_set_parameters_callback(self._on_set_parameters)
        for spec in PARAMETERS:
            self.declare_parameter(spec.name, spec.default, spec.descriptor())
        p = {spec.name: spec.check(self.get_parameter(spec.name).value) for spec in PARAMETERS}
        overrides = None
        if p['scene_overrides'].strip():
            try:
                overrides = safe_load_yaml(p['scene_overrides'], 'parameter scene_overrides')
            except (yaml.YAMLError, YAMLInputError) as exc:
                raise ValueError(
                    f'parameter scene_overrides={p["scene_overrides"]!r} rejected: not YAML '
                    f'({exc})'
                ) from None
            if not isinstance(overrides, dict):
                raise ValueError(
                    f'parameter scene_overrides={p["scene_overrides"]!r} rejected; '
                    f'allowed: empty or a YAML mapping'
                )
        # structured overrides: every scene.<key> parameter given at start-up, declared so that
        # `ros2 param list/describe` shows it; the scene's validation refuses unknown keys, bad
        # values
        names = scene_override_names(self._parameter_overrides)
        for name in names:
            self.declare_parameter(
                name, self._parameter_overrides[name].value, scene_override_descriptor(name)
            )
        if names:
            from pulsejet_sim.scene import merge

            overrides = merge(
                overrides or {}, scene_overrides({n: self.get_parameter(n).value for n in names})
            )
            self.get_logger().info(
                'scene overrides: '
                + ', '.join(f'{n}={self.get_parameter(n).value!r}' for n in names)
            )
        # command_driven: a shell scene's built-in cable routine comes from pulsejet/cmd/* instead
        self.scene = load_scene(p['scene'], overrides=overrides, command_driven=True)
        rate = p['publish_rate_hz'] or float(
            getattr(self.scene, 'publish_rate_hz', 0.0) or DEFAULT_PUBLISH_RATE_HZ
        )
        sim = Simulation(self.scene.model)
        self._warm_up(sim)
        config = eng.SessionConfig(
            pacing=p['pacing'],
            real_time_factor=p['real_time_factor'],
            publish_rate_hz=rate,
            duration_s=p['duration_s'],
            step_count=p['step_count'],
            watchdog_timeout_s=p['watchdog_timeout_s'],
            watchdog_action=p['watchdog_action'],
            watchdog_clock=p['watchdog_clock'],
            control_period_s=p['control_period_s'],
            paused=p['start_paused'],
            lookahead_s=p['lookahead_s'],
        )
        self.session = eng.Session(sim, config, now=time.monotonic())
        self.sim = sim
        self.wait_for_subscribers = p['wait_for_subscribers']
        self.wait_timeout_s = p['wait_timeout_s']
        self.status_name = f'pulsejet: {self.get_fully_qualified_name()}'
        self.frames = (p['odom_frame_id'], p['base_frame_id'])

        reliable = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )
        # best effort matches reliable and best-effort publishers alike
        commands_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT
        )
        self._pubs = {
            topic: self.create_publisher(messages.message_class(topic), topic, reliable)
            for topic in tuple(messages.STATE_TOPICS)
            + (messages.TOPIC_ENERGY_LEDGER, messages.TOPIC_APPLIED_COMMAND)
        }
        self.has_profile = sim.profile() is not None
        # the meridian (tens of points) at most PROFILE_RATE_MAX_HZ: at 1 kHz it would cost more
        # than the rest of the state; every ledger publication carries one too
        self._profile_every = max(1, int(math.ceil(rate / PROFILE_RATE_MAX_HZ - 1e-9)))
        self._states_built = 0
        if self.has_profile:
            self._pubs[messages.TOPIC_MANTLE_PROFILE] = self.create_publisher(
                messages.message_class(messages.TOPIC_MANTLE_PROFILE),
                messages.TOPIC_MANTLE_PROFILE,
                reliable,
            )
            from visualization_msgs.msg import Marker

            self._pubs[messages.TOPIC_MANTLE_MARKER] = self.create_publisher(
                Marker, messages.TOPIC_MANTLE_MARKER, reliable
            )
        from diagnostic_msgs.msg import DiagnosticArray

        self._diag_pub = self.create_publisher(
            DiagnosticArray, messages.TOPIC_DIAGNOSTICS, reliable
        )
        for topic, field in messages.COMMAND_FIELDS.items():
            self.create_subscription(Float64, topic, self._on_actuator(topic, field), commands_qos)
        self.create_subscription(
            JointState, messages.TOPIC_CMD_COMMAND, self._on_command, commands_qos
        )
        self.create_service(SetBool, messages.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, messages.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, messages.SERVICE_RESET, self._on_reset)
        self.tick_period_s = 1.0 / rate
        self.wait_started = time.monotonic()
        self._waiting_published = False
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics)
        self._ready = True
        c = config
        self.get_logger().info(
            f'scene {self.scene.name!r} ({sim.model.name} model, dt {sim.model.dt_s:g} s), '
            'publishing every '
            f'{self.session.publish_every} steps ({rate:g} Hz), pacing {c.pacing}'
            + (f' x{c.real_time_factor:g}' if c.pacing == 'real_time' else '')
            + (', paused' if c.paused else '')
            + ', '
            + (f'duration {c.duration_s:g} s' if c.duration_s > 0 else 'running until stopped')
            + (
                f', watchdog {c.watchdog_timeout_s:g} s of {c.watchdog_clock} time '
                f'({c.watchdog_action})'
                if c.watchdog_timeout_s > 0
                else ''
            )
        )

    # -- process hooks (node_main.run_node) -----------------------------------------------------
    @property
    def done(self) -> bool:
        # only once the session's last events (its final log line, the ledger) are out
        return self._finished

    @property
    def exit_code(self) -> int:
        return self.session.exit_code

    def start(self):
        if self._pacing_thread is None:
            self._pacing_thread = threading.Thread(
                target=self._pacing_loop, name='sim_node pacing', daemon=True
            )
            self._pacing_thread.start()
            self._outbox.start()

    def close(self):
        self._stop_pacing.set()
        self._wake.set()
        if self._pacing_thread is not None:
            self._pacing_thread.join(2.0)
        self._outbox.close()

    def on_stop(self, signum):
        if signum is not None:
            self.get_logger().info(
                f'{signal.Signals(signum).name} received at t={self.sim.time_s:.3f} s; shutting '
                'down'
            )

    def _warm_up(self, sim):
        """
        Take one step and a reset.

        So that JIT compilation does not eat the first real-time period.
        """
        try:
            sim.step(1, sim.command)
            sim.energy_ledger()
            sim.stable_step_s()
        except SimulationBlowUp as exc:
            self.get_logger().error(f'physics blew up on the first step: {exc}')
        sim.reset()

    # -- pacing thread --------------------------------------------------------------------------
    def _pacing_loop(self):
        period = self.tick_period_s
        next_tick = time.monotonic()
        while not self._stop_pacing.is_set() and not self.session.done:
            # before draining: a command arriving from here on wakes the wait below
            self._wake.clear()
            now = time.monotonic()
            try:
                with self._lock:
                    self._apply_inbox()  # in closed_loop pacing this runs the next control period
                    if now >= next_tick:
                        self._emit(self._tick(now))
                        next_tick += period
                        # more than a period late: restart the grid (no burst)
                        if next_tick < now - period:
                            next_tick = now
            except Exception as exc:  # a bug: report it, stop the node with a failure
                import traceback

                traceback.print_exc()
                self.get_logger().error(f'pacing thread stopped: {type(exc).__name__}: {exc}')
                self.session.exit_code = 2
                self.session.done = self._finished = True
                return
            delay = next_tick - time.monotonic()
            if delay > 0:
                self._wake.wait(delay)  # a command (or the stop) wakes the loop early

    def _tick(self, now: float) -> list:
        s = self.session
        if s.started:
            return s.tick(now)
        if self.wait_for_subscribers > 0:
            have = self.count_subscribers(messages.TOPIC_CLOCK)
            if have < self.wait_for_subscribers:
                if now - self.wait_started < self.wait_timeout_s:
                    if not self._waiting_published:
                        self._waiting_published = True
                        return [eng.Publish(self.sim.observe())]
                    return []
                self.get_logger().warning(
                    f'only {have} of {self.wait_for_subscribers} /clock subscribers after '
                    f'{self.wait_timeout_s:g} s; starting anyway'
                )
        return s.start(now)

    # -- events -> messages ---------------------------------------------------------------------
    def _emit(self, events):
        self._emit_events(events)
        if self.session.done:
            self._outbox.flush()
            self._finished = True

    def _emit_events(self, events):
        log = self.get_logger()
        for e in events:
            if isinstance(e, eng.Publish):
                calls = self._publication(e.observation, e.ledger)
                if e.due_wall is not None:  # computed ahead: the outbox sends it at its wall time
                    self._outbox.put(e.due_wall, calls)
                    self._outbox_due = e.due_wall
                else:
                    self._send_now(calls)
            elif isinstance(e, eng.Applied):
                call = functools.partial(
                    self._pubs[messages.TOPIC_APPLIED_COMMAND].publish,
                    messages.applied_command_message(e.command, e.time_s),
                )
                if self._outbox.pending():  # right after the last state computed without it
                    self._outbox.put(self._outbox_due, [call])
                else:  # after a batch the outbox thread may be sending right now
                    self._send_now([call])
            elif isinstance(e, eng.PublishLedger):
                self._send_now(self._ledger_publication(e.time_s))
            elif isinstance(e, eng.Log):  # one call site per severity (rclpy requires it)
                if e.level == 'error':
                    log.error(e.text)
                elif e.level == 'warning':
                    log.warning(e.text)
                else:
                    log.info(e.text)
            elif isinstance(e, eng.Halted):
                self._outbox.flush()
                self._publish_diagnostics()

    def _send_now(self, calls):
        self._outbox.flush()  # what was computed earlier goes first
        for call in calls:
            call()

    def _publication(self, obs, ledger=False) -> list:
        """Return the publish calls of one state, its messages built now (they hold this state)."""
        if not eng.observation_is_finite(obs):  # never publish NaN
            return []
        calls = []
        self._states_built += 1
        profile = None
        if self.has_profile and (ledger or self._states_built % self._profile_every == 0):
            profile = self.sim.profile()
            if not all(np.isfinite(arr).all() for arr in profile):
                profile = None
        if profile is not None:  # before /clock, which the state's consumers take as its end
            calls.append(
                functools.partial(
                    self._pubs[messages.TOPIC_MANTLE_PROFILE].publish,
                    messages.profile_message(*profile, obs.time_s),
                )
            )
        for topic, msg in messages.observation_messages(obs, messages.FRAME_ID, *self.frames):
            calls.append(functools.partial(self._pubs[topic].publish, msg))
        if ledger:
            calls += self._ledger_publication(obs.time_s)
            marker = self._pubs.get(messages.TOPIC_MANTLE_MARKER)
            # the 3-D view at the ledger's rate, in the odometry's body frame, and only while
            # someone looks: its ~14000 points take ~15 ms of the GIL to build and send
            if profile is not None and marker is not None and marker.get_subscription_count():
                calls.append(
                    functools.partial(
                        marker.publish,
                        messages.mantle_marker(*profile, obs.time_s, self.frames[1]),
                    )
                )
        return calls

    def _ledger_publication(self, time_s) -> list:
        values = self.sim.energy_ledger()
        if not all(math.isfinite(v) for v in values.values()):
            return []
        return [
            functools.partial(
                self._pubs[messages.TOPIC_ENERGY_LEDGER].publish,
                messages.ledger_message(values, time_s),
            )
        ]

    # -- commands -------------------------------------------------------------------------------
    def _on_actuator(self, topic, field):
        def callback(msg: Float64):
            self._accept({field: msg.data}, None, topic)

        return callback

    def _on_command(self, msg: JointState):
        try:
            stamp_s, values = messages.command_values(msg)
        except ValueError as exc:
            # counted and logged in order with the others, by the pacing thread
            self._accept(
                None, None, f'{messages.TOPIC_CMD_COMMAND}: rejected: {exc}; command kept'
            )
            return
        self._accept(values, stamp_s, messages.TOPIC_CMD_COMMAND)

    def _accept(self, values, stamp_s, source):
        self._inbox.append((values, stamp_s, source, time.monotonic()))
        self._wake.set()

    def _apply_inbox(self):
        """Apply the commands received so far (under the lock, before any stepping or service)."""
        while self._inbox:
            values, stamp_s, source, received = self._inbox.popleft()
            if values is None:  # a message that did not parse; `source` holds the reason
                self.session.command_counts['rejected'] += 1
                self._warn_rejected(source)
                continue
            try:
                events = self.session.accept(values, received, stamp_s, source)
            except CommandError as exc:
                self._warn_rejected(f'{source}: {exc}; command kept at {self.session.command}')
                continue
            self._emit(events)

    def _warn_rejected(self, text):
        # a token bucket: a publisher flooding bad values must not spend the node's time on logging
        now = time.monotonic()
        self._warn_tokens = min(
            REJECTION_LOG_BURST,
            self._warn_tokens + (now - self._warn_refilled) * REJECTION_LOG_RATE_HZ,
        )
        self._warn_refilled = now
        if self._warn_tokens < 1.0:
            self._warn_suppressed += 1
            return
        self._warn_tokens -= 1.0
        if self._warn_suppressed:
            text += (
                f' ({self._warn_suppressed} more rejections not logged; '
                'see commands_rejected in /diagnostics)'
            )
            self._warn_suppressed = 0
        self.get_logger().warning(text)

    # -- parameters and services ----------------------------------------------------------------
    def _on_set_parameters(self, params):
        with self._lock:
            self._apply_inbox()
            checked, rejection = check_parameters(params, PARAMETER_SPECS)
            if (
                rejection is not None or not self._ready
            ):  # at declaration the values are read in __init__
                return rejection or SetParametersResult(successful=True)
            for name, value in checked.items():
                if name in LIVE_CONFIG and value != getattr(self.session.config, name):
                    self._emit(self.session.configure(name, value, time.monotonic()))
                    self.get_logger().info(f'{name} set to {value}')
            return SetParametersResult(successful=True)

    def _on_pause(self, request, response):
        with self._lock:
            self._apply_inbox()
            response.success, response.message, events = self.session.pause(
                bool(request.data), time.monotonic()
            )
            self._emit(events)
        return response

    def _on_step(self, request, response):
        with self._lock:
            self._apply_inbox()
            response.success, response.message, events = self.session.step(time.monotonic())
            self._emit(events)
        return response

    def _on_reset(self, request, response):
        with self._lock:
            self._apply_inbox()
            message, events = self.session.reset(time.monotonic())
            self._emit(events)
        response.success = True
        response.message = f'scene {self.scene.name!r}: {message}'
        return response

    # -- diagnostics ----------------------------------------------------------------------------
    def _publish_diagnostics(self):
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        with self._lock:
            self._apply_inbox()
            level, message, values = self.session.health(time.monotonic())
            status = DiagnosticStatus(
                level={
                    eng.OK: DiagnosticStatus.OK,
                    eng.WARN: DiagnosticStatus.WARN,
                    eng.ERROR: DiagnosticStatus.ERROR,
                }[level],
                name=self.status_name,
                message=message,
                hardware_id=self.get_fully_qualified_name(),
            )
            status.values = [
                KeyValue(
                    key=k,
                    value=(
                        (repr(float(v)) if math.isfinite(v) else 'n/a')
                        if isinstance(v, float)
                        else str(v)
                    ),
                )
                for k, v in values.items()
            ]
            msg = DiagnosticArray()
            msg.header.stamp = messages.stamp(self.sim.time_s)
            msg.header.frame_id = messages.FRAME_ID
            msg.status = [status]
            self._diag_pub.publish(msg)


def main(args=None):
    from pulsejet_sim.ros.node_main import run_node

    # the pacing thread must get the GIL within a fraction of a publication period when the
    # executor thread is busy (CPython's default switch interval is 5 ms); the kernels release it
    # while stepping
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node('sim_node', SimNode, args)


if __name__ == '__main__':
    sys.exit(main())
