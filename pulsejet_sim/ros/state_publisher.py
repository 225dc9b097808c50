"""
sim_node's publishers, and the publish calls of each engine event (messages built at once).

A state's messages are built when the state is computed, so that they hold that state even when
they are sent later (`lookahead_s`: the outbox sends them at their wall time); each method returns
the calls, the caller decides when to run them.
"""

from __future__ import annotations

import functools
import math
import threading
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
import numpy as np
from pulsejet_sim.bag.cdr import stamp_ns, TopicEncoder
from pulsejet_sim.engine.session import observation_is_finite
from pulsejet_sim.ros import messages
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker

#: the meridian (tens of points) at most this often: at 1 kHz it would cost more than the rest of
#: the state; every ledger publication carries one too
PROFILE_RATE_MAX_HZ = 100.0
#: samples kept for a reliable subscriber that lags (a recorder on a busy machine): in a
#: closed-loop run nothing paces the states, and KEEP_LAST drops a sample not yet acknowledged
#: once this many newer ones are sent (replay keeps as many)
QOS_DEPTH = 100
#: odom -> body, as every ROS odometry source broadcasts it (absolute: robots sharing a domain
#: share the TF tree, frame_prefix keeps their frames apart)
TOPIC_TF = '/tf'
TF_QOS_DEPTH = 100
#: the header frame of what is not a place or a direction (diagnostics, the energy ledger), empty
#: as diagnostic_updater leaves it: a frame would name something no TF tree holds
NO_FRAME = ''

Call = Callable[[], object]


def tf_message_class():
    """Return tf2_msgs' TFMessage, or None where tf2_msgs is not installed (the PyPI wheels)."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class LatestJobThread:
    """
    A thread that runs the latest job handed to it; a job handed over while one waits replaces it.

    For what a viewer alone needs (the mantle Marker): the caller (the pacing thread) only hands
    over its inputs; building and sending happen here, and a viewer too slow to keep up gets fewer
    messages instead of delaying the states.
    """

    def __init__(self, name: str, on_error: Callable[[str], None]):
        self._cond = threading.Condition()
        self._job = None
        self._stop = False
        self._on_error = on_error
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Callable[[], object]) -> None:
        with self._cond:
            self._job = job
            self._cond.notify()

    def close(self, timeout_s: float = 2.0) -> None:
        """Run the job still waiting, then stop the thread."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._job is None and not self._stop:
                    self._cond.wait()
                job, self._job = self._job, None
                if job is None:  # stopped with nothing left
                    return
            try:
                job()
            except Exception as exc:  # a publish after shutdown: say it, go on
                self._on_error(f'{type(exc).__name__}: {exc}')


class StatePublisher:
    """
    The publishers of one simulated robot on `node`.

    sim: the Simulation (its profile and energy ledger are read when a state is built);
    frames: (odom frame, body frame), REP 105: the odometry's pose is in the first, everything
    body-fixed (twist, velocity, thrust, profile, Marker) in the second;
    publish_tf: odom -> body on /tf with every state, if tf2_msgs is installed (`has_tf` says).
    """

    def __init__(
        self, node, sim, publish_rate_hz: float, frames: tuple[str, str], publish_tf: bool = True
    ):
        self.sim = sim
        self.frames = frames
        classes = {
            topic: messages.message_class(topic)
            for topic in messages.STATE_TOPICS
            + (messages.TOPIC_ENERGY_LEDGER, messages.TOPIC_APPLIED_COMMAND)
        }
        classes[messages.TOPIC_DIAGNOSTICS] = DiagnosticArray
        self.has_profile = sim.profile() is not None
        if self.has_profile:
            classes[messages.TOPIC_MANTLE_PROFILE] = messages.message_class(
                messages.TOPIC_MANTLE_PROFILE
            )
            classes[messages.TOPIC_MANTLE_MARKER] = Marker
        self._pubs = {
            topic: node.create_publisher(cls, topic, messages.reliable_qos(topic, QOS_DEPTH))
            for topic, cls in classes.items()
        }
        self.tf_message = tf_message_class() if publish_tf else None
        self.has_tf = self.tf_message is not None
        if self.has_tf:
            # tf2_ros's TransformBroadcaster: /tf (not namespaced), reliable, volatile, depth 100
            self._pubs[TOPIC_TF] = node.create_publisher(
                self.tf_message,
                TOPIC_TF,
                QoSProfile(depth=TF_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE),
            )
        elif publish_tf:
            node.get_logger().info(
                f'no {TOPIC_TF}: tf2_msgs is not installed (odom -> {frames[1]} is in the '
                f'odometry on {messages.TOPIC_ODOMETRY} only)'
            )
        self._profile_every = max(1, int(math.ceil(publish_rate_hz / PROFILE_RATE_MAX_HZ - 1e-9)))
        # every state message as CDR bytes straight from the values (bag.cdr, the bytes the
        # offline runner records and rclpy would serialise): building and converting rclpy
        # message objects was most of the time between a wake-up and /clock's send (the profile
        # as one Point32 object per node alone ~0.6 ms a state)
        self._encoder = TopicEncoder(frame_id=frames[1], odom_frame_id=frames[0],
                                     base_frame_id=frames[1])
        self._unframed_encoder = TopicEncoder(frame_id=NO_FRAME)
        # the Marker (~350 kB) is built and sent off the pacing thread
        self._marker_thread = (
            LatestJobThread(
                'mantle marker',
                lambda text: node.get_logger().warning(f'mantle marker not sent: {text}'),
            )
            if self.has_profile
            else None
        )
        self._states_built = 0

    def topic_names(self) -> list[str]:
        """
        Return the resolved names of every topic published here but /tf.

        /tf is shared by every node of the domain (and the recorder does not take it by default):
        its subscribers say nothing about this node's.
        """
        return [pub.topic_name for topic, pub in self._pubs.items() if topic != TOPIC_TF]

    def _call(self, topic: str, msg) -> Call:
        return functools.partial(self._pubs[topic].publish, msg)

    def state(self, obs, ledger: bool = False, sent_at_once: bool = False) -> list[Call]:
        """
        Return the publish calls of one state; none for a non-finite one (never NaN).

        sent_at_once: the caller runs the calls before the simulation moves on (no lookahead, no
        publish delay); the energy ledger and the Marker of a ledger state are then built by a
        call after /clock's instead of here, so their cost (the Marker's build 0.8 ms and the
        ledger's 0.1 ms median on the shell scene, benchmarks/results/pacing_trace.md) is not in
        the time from the state's wake-up to its /clock. Same messages: the simulation still holds
        this state when they are built.
        """
        if not observation_is_finite(obs):
            return []
        calls = []
        self._states_built += 1
        profile = None
        if self.has_profile and (ledger or self._states_built % self._profile_every == 0):
            profile = self.sim.profile()
            if not all(np.isfinite(arr).all() for arr in profile):
                profile = None
        ns = stamp_ns(obs.time_s)
        if profile is not None:  # before /clock, which the state's consumers take as its end
            calls.append(
                self._call(messages.TOPIC_MANTLE_PROFILE, self._encoder.profile(*profile, ns))
            )
        for topic, data in self._encoder.observation(obs, ns):
            calls.append(self._call(topic, data))
            if topic == messages.TOPIC_ODOMETRY and self.has_tf:
                odometry = messages.odometry_message(obs, *self.frames)
                calls.append(self._call(TOPIC_TF, self._transform(odometry)))
        if ledger:
            if sent_at_once:
                calls.append(functools.partial(self._ledger_extras, obs.time_s, profile))
            else:
                calls += self._ledger_extras_calls(obs.time_s, profile)
        return calls

    def _ledger_extras(self, time_s: float, profile) -> None:
        """Build and send a ledger state's energy ledger and Marker (after its /clock)."""
        for call in self._ledger_extras_calls(time_s, profile):
            call()

    def _ledger_extras_calls(self, time_s: float, profile) -> list[Call]:
        """Return the calls of a ledger state's energy ledger and Marker, their values read now."""
        calls = self.ledger(time_s)
        marker = self._pubs.get(messages.TOPIC_MANTLE_MARKER)
        # the 3-D view at the ledger's rate, in the body frame, and only while someone looks;
        # serialised from arrays (its ~14000 points as Python objects held the interpreter ~15 ms)
        # on the marker thread, handed over when the state is sent (so at its wall time with a
        # lookahead), published as those bytes
        if profile is not None and marker.get_subscription_count():
            r_m, z_m = (np.array(a, dtype=np.float64) for a in profile)  # this state's
            calls.append(
                functools.partial(
                    self._marker_thread.submit,
                    functools.partial(self._send_marker, marker, r_m, z_m, time_s),
                )
            )
        return calls

    def _send_marker(self, publisher, r_m, z_m, time_s: float) -> None:
        publisher.publish(messages.mantle_marker_cdr(r_m, z_m, time_s, self.frames[1]))

    def close(self) -> None:
        """Send the Marker still waiting, stop the marker thread."""
        if self._marker_thread is not None:
            self._marker_thread.close()

    def _transform(self, odometry):
        """Return the odometry's pose as the odom -> body transform (a TFMessage of one)."""
        t = TransformStamped()
        t.header = odometry.header
        t.child_frame_id = odometry.child_frame_id
        position = odometry.pose.pose.position
        t.transform.translation.x = position.x
        t.transform.translation.y = position.y
        t.transform.translation.z = position.z
        t.transform.rotation = odometry.pose.pose.orientation
        return self.tf_message(transforms=[t])

    def ledger(self, time_s: float) -> list[Call]:
        """Return the energy ledger's publish call (none while a value is not finite)."""
        values = self.sim.energy_ledger()
        if not all(math.isfinite(v) for v in values.values()):
            return []
        data = self._unframed_encoder.ledger(values, stamp_ns(time_s))
        return [self._call(messages.TOPIC_ENERGY_LEDGER, data)]

    def applied(self, command, time_s: float) -> Call:
        """Return the publish call of the command held from `time_s` on."""
        return self._call(
            messages.TOPIC_APPLIED_COMMAND,
            self._unframed_encoder.applied_command(command, stamp_ns(time_s)),
        )

    def diagnostics(self, level: str, name: str, hardware_id: str, message: str, values) -> None:
        """Publish sim_node's health (level OK | WARN | ERROR) now, at the simulation time."""
        msg = messages.health_message(
            level, name, hardware_id, message, values, self.sim.time_s, NO_FRAME
        )
        self._pubs[messages.TOPIC_DIAGNOSTICS].publish(msg)
