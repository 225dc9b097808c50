"""
ROS 2 node around the ROS-free engine `pulsejet_sim.engine.session.Session`.

Parameters, topics, services and /diagnostics; the session paces the physics and says what to
publish.

Parameters: `pulsejet_sim.ros.sim_node_params` (`ros2 param describe /sim_node <name>` shows
them).

Topic, service and status names: `pulsejet_sim.core.topics` (one place for every name). Commands
arrive per actuator (std_msgs/Float64) or atomically on pulsejet/cmd/command
(sensor_msgs/JointState, every named actuator at the same step); subscriptions are best effort, so
reliable and best-effort publishers both connect. A non-finite or out-of-range value is rejected
with a warning naming it (throttled; /diagnostics counts every one); the held command is kept.
Commands reach the pacing thread (`pulsejet_sim.engine.live_loop.LiveLoop`) through an inbox, so
the executor never waits for a physics batch; the kernels release the GIL while they step. Reset
returns to the scene's initial state and command at time 0 (/clock jumps back, like a Gazebo world
reset). A real_time state is computed at its wall time, its messages built at once as CDR bytes,
and sent publish_delay_periods of a period later by the outbox thread: what varies in computing
it stays out of the send times. The diagnostic status is named after the
node's fully qualified name, so two robots in one domain stay apart.
Exit code: 0 on duration reached or SIGINT/SIGTERM, 1 when stopped after a blow-up, 2 on a bad
scene or parameter.
"""

from __future__ import annotations

import functools
import signal
import sys
import time

from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.engine import session as eng
from pulsejet_sim.engine.live_loop import LiveLoop
from pulsejet_sim.engine.outbox import TimedOutbox
from pulsejet_sim.ros import messages
from pulsejet_sim.ros import sim_node_params as params
from pulsejet_sim.ros.node_params import check_parameters
from pulsejet_sim.ros.state_publisher import StatePublisher
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

GIL_SWITCH_INTERVAL_S = 2e-4
#: command-rejection warnings: a burst of this many, then this many per second; the rest are only
#: counted (commands_rejected in /diagnostics) and summed up in the next warning
REJECTION_LOG_BURST = 10
REJECTION_LOG_RATE_HZ = 2.0
#: the event _tick adds when /diagnostics is due (sim_node's own; the session never sees it)
DIAGNOSTICS_DUE = object()


class SimNode(Node):

    def __init__(self, **kwargs):
        super().__init__('sim_node', **kwargs)
        from pulsejet_sim.engine.simulation import Simulation

        self._ready = False
        self._outbox = TimedOutbox(name='sim_node publication')  # states computed ahead
        self._outbox_due = None  # wall time of the last batch put there
        self._rejection_log = eng.LogThrottle(REJECTION_LOG_BURST, REJECTION_LOG_RATE_HZ)
        self._finished = False
        self.add_on_set_parameters_callback(self._on_set_parameters)
        p = params.declare(self)
        self.executor_kind = p['executor']  # run_node spins the node on this executor
        self.scene = params.load_scene_from_parameters(self, p)
        rate = p['publish_rate_hz'] or float(
            getattr(self.scene, 'publish_rate_hz', 0.0) or params.DEFAULT_PUBLISH_RATE_HZ
        )
        sim = Simulation(self.scene.model)
        self._warm_up(sim)
        config = params.session_config(p, rate)
        self.session = eng.Session(sim, config, now=time.monotonic())
        self.sim = sim
        # commands, services, parameters and diagnostics reach the session through the loop
        self.loop = LiveLoop(
            self.session, 1.0 / rate, self._emit, self._warn_rejected, self._on_failure, self._tick
        )
        self.wait_for_subscribers = p['wait_for_subscribers']
        self.wait_timeout_s = p['wait_timeout_s']
        self.status_name = f'pulsejet: {self.get_fully_qualified_name()}'
        prefix = p['frame_prefix']
        self.out = StatePublisher(
            self,
            sim,
            rate,
            (prefix + p['odom_frame_id'], prefix + p['base_frame_id']),
            publish_tf=p['publish_tf'],
        )
        self.wait_topics = self._topics_to_wait_for(p['wait_for_topics'])
        # best effort matches reliable and best-effort publishers alike
        commands_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT
        )
        for topic, field in messages.COMMAND_FIELDS.items():
            self.create_subscription(Float64, topic, self._on_actuator(topic, field), commands_qos)
        self.create_subscription(
            JointState, messages.TOPIC_CMD_COMMAND, self._on_command, commands_qos
        )
        self.create_service(SetBool, messages.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, messages.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, messages.SERVICE_RESET, self._on_reset)
        self.wait_started = time.monotonic()
        self._waiting_published = False
        # /diagnostics is published by the pacing thread right after a tick's sends (see _tick),
        # not by an rclpy timer: a timer of a whole number of publication periods fires at the
        # same phase of the send grid all run long, and where that phase met the send time it
        # delayed one send in a hundred (at 1 Hz and 100 Hz) by the diagnostics' 0.5 ms
        self._diagnostics_period_s = p['diagnostics_period_s']
        self._next_diagnostics = None
        self._ready = True
        self.get_logger().info(
            f'scene {self.scene.name!r} ({sim.model.name} model, dt {sim.model.dt_s:g} s), '
            f'publishing every {self.session.publish_every} steps ({rate:g} Hz), '
            + config.describe()
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
        self._outbox.start()
        self.loop.start()

    def close(self):
        self.loop.close()
        self._outbox.close()
        self.out.close()

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

    # -- pacing thread (LiveLoop) ---------------------------------------------------------------
    def _tick(self, now: float) -> list:
        events = self._session_tick(now)
        if self._next_diagnostics is None:
            self._next_diagnostics = now + self._diagnostics_period_s
        elif now >= self._next_diagnostics:
            # after the tick's states: their sends come first (_emit_events)
            self._next_diagnostics = max(self._next_diagnostics + self._diagnostics_period_s, now)
            events.append(DIAGNOSTICS_DUE)
        return events

    def _session_tick(self, now: float) -> list:
        s = self.session
        if s.started:
            return s.tick(now)
        missing = self._subscribers_missing()
        if missing:
            if now - self.wait_started < self.wait_timeout_s:
                if not self._waiting_published:
                    self._waiting_published = True
                    return [eng.Publish(self.sim.observe())]
                return []
            self.get_logger().warning(
                f'after {self.wait_timeout_s:g} s still waiting for {"; ".join(missing)}; '
                'starting anyway'
            )
        return s.start(now)

    def _topics_to_wait_for(self, entries) -> list[str]:
        """Resolve wait_for_topics: '*' = every topic published here (ValueError: a bad name)."""
        topics = []
        for entry in entries:
            if entry == '*':
                topics += self.out.topic_names()
                continue
            try:
                topics.append(self.resolve_topic_name(entry))
            except Exception as exc:  # rclpy's InvalidTopicNameException and kin
                raise ValueError(
                    f'parameter wait_for_topics entry {entry!r} rejected: {exc}; allowed: a '
                    'topic name or "*"'
                ) from None
        return sorted(set(topics))

    def _subscribers_missing(self) -> list[str]:
        """Return what the start still waits for (wait_for_subscribers, wait_for_topics), or []."""
        missing = []
        if self.wait_for_subscribers > 0:
            have = self.count_subscribers(messages.TOPIC_CLOCK)
            if have < self.wait_for_subscribers:
                missing.append(f'{self.wait_for_subscribers} /clock subscribers (have {have})')
        unsubscribed = [t for t in self.wait_topics if self.count_subscribers(t) == 0]
        if unsubscribed:
            missing.append('a subscriber of ' + ', '.join(unsubscribed))
        return missing

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
                ahead = e.due_wall is not None and e.due_wall > time.monotonic()
                calls = self.out.state(e.observation, e.ledger, sent_at_once=not ahead)
                if ahead:
                    # computed ahead of its send time: the outbox sends it then
                    self._outbox.put(e.due_wall, calls)
                    self._outbox_due = e.due_wall
                else:
                    self._send_now(calls)
            elif isinstance(e, eng.Applied):
                call = self.out.applied(e.command, e.time_s)
                if self._outbox.pending():  # right after the last state computed without it
                    self._outbox.put(self._outbox_due, [call])
                else:  # after a batch the outbox thread may be sending right now
                    self._send_now([call])
            elif isinstance(e, eng.PublishLedger):
                self._send_now(self.out.ledger(e.time_s))
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
            elif e is DIAGNOSTICS_DUE:  # the pacing thread, holding the session
                call = functools.partial(
                    self._send_diagnostics, *self.session.health(time.monotonic())
                )
                if self._outbox.pending():  # right after the states it will send
                    self._outbox.put(self._outbox_due, [call])
                else:  # right after the states just sent
                    call()

    def _on_failure(self, text):
        self.get_logger().error(text)
        self._finished = True

    def _send_now(self, calls):
        self._outbox.flush()  # what was computed earlier goes first
        for call in calls:
            call()

    # -- commands -------------------------------------------------------------------------------
    def _on_actuator(self, topic, field):
        def callback(msg: Float64):
            self.loop.accept({field: msg.data}, None, topic)

        return callback

    def _on_command(self, msg: JointState):
        try:
            stamp_s, values = messages.command_values(msg)
        except ValueError as exc:
            self.loop.reject(f'{messages.TOPIC_CMD_COMMAND}: rejected: {exc}; command kept')
            return
        self.loop.accept(values, stamp_s, messages.TOPIC_CMD_COMMAND)

    def _warn_rejected(self, text):
        text = self._rejection_log.admit(text, time.monotonic())
        if text is not None:  # the count of the others is in /diagnostics (commands_rejected)
            self.get_logger().warning(text)

    # -- parameters and services ----------------------------------------------------------------
    def _on_set_parameters(self, parameters):
        checked, rejection = check_parameters(parameters, params.PARAMETER_SPECS)
        if rejection is not None or not self._ready:  # at declaration __init__ reads the values
            return rejection or SetParametersResult(successful=True)
        with self.loop.locked():
            for name, value in checked.items():
                if name in params.LIVE_CONFIG and value != getattr(self.session.config, name):
                    self._emit(self.session.configure(name, value, time.monotonic()))
                    self.get_logger().info(f'{name} set to {value}')
        return SetParametersResult(successful=True)

    def _on_pause(self, request, response):
        with self.loop.locked():
            response.success, response.message, events = self.session.pause(
                bool(request.data), time.monotonic()
            )
            self._emit(events)
        return response

    def _on_step(self, request, response):
        with self.loop.locked():
            response.success, response.message, events = self.session.step(time.monotonic())
            self._emit(events)
        return response

    def _on_reset(self, request, response):
        with self.loop.locked():
            message, events = self.session.reset(time.monotonic())
            self._emit(events)
        response.success = True
        response.message = f'scene {self.scene.name!r}: {message}'
        return response

    # -- diagnostics ----------------------------------------------------------------------------
    def _publish_diagnostics(self):
        # only the snapshot holds the pacing thread; building and publishing the message does not
        # need the session
        with self.loop.locked():
            level, message, values = self.session.health(time.monotonic())
        self._send_diagnostics(level, message, values)

    def _send_diagnostics(self, level: str, message: str, values: dict) -> None:
        self.out.diagnostics(
            level, self.status_name, self.get_fully_qualified_name(), message, values
        )


def main(args=None):
    from pulsejet_sim.ros.node_main import run_node

    # the pacing thread must get the GIL within a fraction of a publication period when the
    # executor thread is busy (CPython's default switch interval is 5 ms); the kernels release it
    # while stepping
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    return run_node('sim_node', SimNode, args)


if __name__ == '__main__':
    sys.exit(main())
