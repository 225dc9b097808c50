"""
ROS 2 node `replay`: publish a recorded MCAP (recorder node or `pulsejet run`) with its timing.

Every message is published on its original (stored, fully qualified) topic with its original type,
as the raw CDR bytes of the file (no decoding). Message i is published at wall time

    start + (log_time_i - first_log_time - start_offset) / rate

measured against one start time (no cumulative drift; when publishing falls behind it catches up
without sleeping). Log times are simulation time for `pulsejet run` files and wall-clock receive
times for recorder files, so either plays back at its recorded pace.

    ros2 run pulsejet_sim replay --ros-args -p bag:=runs/x.mcap -p rate:=2.0
    python -m pulsejet_sim.ros.replay --ros-args -p bag:=runs/x.mcap -p loop:=true

Parameters (read-only, declared with descriptors: `ros2 param describe /replay rate`; see
parameter_specs)
  bag             path of the MCAP recording (required)
  rate            playback speed factor, finite > 0 (default 1.0; 2.0 = twice as fast)
  loop            restart at the end until stopped (default false)
  start_offset_s  skip the first seconds of the recording (default 0.0; < its duration)
  topics          string array: replay only these topics (default: all); '/clock' is governed by
                  publish_clock, not by this list
  publish_clock   drive /clock (default true): the recorded /clock messages when the file has any,
                  else a clock generated from the log times at clock_rate_hz of wall time (like
                  `ros2 bag play --clock`), so nodes with use_sim_time follow the replay
  clock_rate_hz   rate of the generated clock (default 100; only used without a recorded /clock)
  wait_for_topics string array: before playing, wait until each of these replayed topics has a
                  matched subscription (default: none; lets a consumer started together with the
                  replay receive the first messages)
  delay_s         wall seconds to wait before playing, after wait_for_topics (default 0.0)
  replay_commands also replay the recorded commands (pulsejet/cmd/*) when `topics` is not given
                  (default false: a replay next to a live sim_node must not drive it; a topic
                  listed in `topics` is always replayed)

A bad parameter (missing file, not an MCAP, rate <= 0 or NaN, unknown topic...) prints one line
`replay: error: <name>=<value> rejected; allowed: ...` to stderr and exits 2. The node exits 0 at
the end of the recording (unless loop) and on SIGINT/SIGTERM (after the messages already published
were acknowledged by the subscribers, at most 2 s).

Looping: every pass restarts at the beginning, so /clock JUMPS BACK to the start of the recording
at each pass (a consumer with use_sim_time sees time go backwards: rclpy time-jump callbacks fire,
timers and TF buffers may need a reset). Stamps in the messages repeat too.

QoS: every topic except /clock is published reliable, keep-last 100, volatile. /clock is published
reliable keep-last 100, volatile, which matches best-effort and reliable subscriptions alike.

The whole file is loaded into memory and sorted by log time (stable, so messages with the same log
time keep their file order; a generated clock tick is published before messages at the same time).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import importlib
import math
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any, Sequence

from pulsejet_sim.bag.reader import BagInfo, BagReadError, iter_bag
from pulsejet_sim.core.schema import Flag, Number

CLOCK_TOPIC = '/clock'
CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'
QOS_DEPTH = 100  # published samples kept for a slow subscriber
MAX_SLEEP_S = 0.05  # longest single sleep: a stop request is seen within this time
ACK_TIMEOUT_S = 2.0  # at exit, wait at most this long for subscribers to acknowledge
MIN_PASS_S = 0.01  # a looping pass lasts at least this long (a one-instant file does not spin)
MAX_CLOCK_TICKS = (
    10_000_000  # generated /clock ticks per pass (a damaged log time must not exhaust memory)
)
PARAMETERS = (
    'bag',
    'rate',
    'loop',
    'start_offset_s',
    'topics',
    'publish_clock',
    'clock_rate_hz',
    'wait_for_topics',
    'delay_s',
    'replay_commands',
)
TOPIC_LIST = 'a list of topic names, e.g. "[\'pulsejet/velocity\', \'/clock\']"'


def parameter_specs() -> dict:
    """
    Return name -> node_params.ParamSpec, as `ros2 param describe /replay` shows them.

    All read-only (the file is played as configured at start-up) and dynamically typed (rate:=2 and
    rate:=2.0 both work): check_config checks the values, before they are declared.
    """
    from pulsejet_sim.ros.node_params import ParamSpec

    inf = math.inf
    specs = (
        ParamSpec(
            'bag', '', 'path of the MCAP recording to play (required)', allowed='an MCAP file path'
        ),
        ParamSpec(
            'rate',
            1.0,
            'playback speed factor (2.0 = twice as fast)',
            0.0,
            inf,
            allowed='a finite number > 0',
        ),
        ParamSpec(
            'loop', False, 'restart at the end until stopped (/clock jumps back at each pass)'
        ),
        ParamSpec(
            'start_offset_s',
            0.0,
            'skip the first seconds of the recording',
            0.0,
            inf,
            allowed="a finite number of seconds >= 0, below the recording's duration",
        ),
        ParamSpec(
            'topics',
            None,
            'replay only these topics (empty: all); /clock is governed by publish_clock',
            allowed=TOPIC_LIST + ' or empty',
        ),
        ParamSpec(
            'publish_clock',
            True,
            'drive /clock: the recorded one, else one generated from the log '
            'times at clock_rate_hz',
        ),
        ParamSpec(
            'clock_rate_hz',
            100.0,
            'rate of the generated /clock in wall time (only without a ' 'recorded /clock)',
            0.0,
            10000.0,
            allowed='a finite rate in (0, 10000] Hz',
        ),
        ParamSpec(
            'wait_for_topics',
            None,
            'before playing, wait until each of these replayed topics has a ' 'subscription',
            allowed=TOPIC_LIST + ' or empty',
        ),
        ParamSpec(
            'delay_s',
            0.0,
            'wall seconds to wait before playing (after wait_for_topics)',
            0.0,
            inf,
            allowed='a finite number of seconds >= 0',
        ),
        ParamSpec(
            'replay_commands',
            False,
            'also replay the recorded pulsejet/cmd/* commands when topics is '
            'empty (a replay next to a live sim_node must not drive it)',
        ),
    )
    return {spec.name: dataclasses.replace(spec, read_only=True, dynamic=True) for spec in specs}


class ConfigError(ValueError):
    """A parameter value that cannot be played (the message names it and what is allowed)."""


@dataclass(frozen=True)
class ReplayConfig:
    bag: Path
    rate: float = 1.0
    loop: bool = False
    start_offset_s: float = 0.0
    topics: tuple[str, ...] | None = None  # qualified names; None = all
    publish_clock: bool = True
    clock_rate_hz: float = 100.0
    wait_for_topics: tuple[str, ...] = ()
    delay_s: float = 0.0
    replay_commands: bool = False


@dataclass
class Recording:
    path: Path
    messages: list[tuple[int, str, bytes]]  # (log_time_ns, qualified topic, CDR) sorted by time
    topics: dict[str, str]  # qualified topic -> type name (every stored topic)
    first_ns: int
    last_ns: int
    truncated: bool = False
    damage: str = ''  # BagInfo.damage_report() of the file ('' when intact)

    @property
    def has_clock(self) -> bool:
        return any(t == CLOCK_TOPIC for _, t, _ in self.messages)


@dataclass(frozen=True)
class Event:
    offset_ns: int  # log time relative to the start of the pass (recording ns, before rate)
    topic: str
    payload: bytes | None  # raw CDR; None: a generated clock tick carrying clock_ns
    clock_ns: int = 0


@dataclass
class Schedule:
    events: list[Event]
    duration_ns: int  # log-time length of one pass (from the start offset to the last message)
    base_ns: int  # log time at offset 0 (first log time + start_offset)
    topics: dict[str, str]  # topics published -> type name
    generated_clock: bool

    def wall_duration_s(self, rate: float) -> float:
        return self.duration_ns * 1e-9 / rate


# ---- parameters ---------------------------------------------------------------------------------
def qualify(topic: str) -> str:
    return topic if topic.startswith('/') else '/' + topic


def _number(
    name: str, value: Any, allowed: str, low: float, low_open: bool, high: float = math.inf
) -> float:
    """Return a parameter's number (a number, or text a number reads from) or ConfigError."""
    rule = Number(None, low, high, low_open=low_open)
    return rule.accept(value, name, error=ConfigError, allowed=allowed, sep='=', from_text=True)


def _boolean(name: str, value: Any) -> bool:
    return Flag(None).accept(value, name, error=ConfigError, sep='=', from_text=True)


def _topic_list(name: str, value: Any) -> tuple[str, ...] | None:
    if value is None or value == '' or (isinstance(value, (list, tuple)) and not value):
        return None
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(t, str) and t.strip('/ ') for t in value
    ):
        raise ConfigError(
            f'{name}={value!r} rejected; allowed: a list of topic names, e.g. '
            f'{name}:="[\'pulsejet/velocity\', \'/clock\']"'
        )
    return tuple(dict.fromkeys(qualify(t.strip()) for t in value))


def check_config(values: dict[str, Any]) -> ReplayConfig:
    """
    Check parameter values and return a ReplayConfig.

    ConfigError names the first bad value and what is allowed. Checks the values only (the file is
    checked by load_recording).
    """
    unknown = sorted(set(values) - set(PARAMETERS))
    if unknown:
        raise ConfigError(f'parameter {unknown[0]!r} is unknown; allowed: {", ".join(PARAMETERS)}')
    bag = values.get('bag')
    if not isinstance(bag, str) or not bag.strip():
        raise ConfigError(
            f'bag={bag!r} rejected; allowed: the path of an MCAP recording (required), '
            'e.g. -p bag:=runs/x.mcap'
        )
    return ReplayConfig(
        bag=Path(bag).expanduser(),
        rate=_number(
            'rate',
            values.get('rate', 1.0),
            'a finite number > 0 (playback speed factor, 1.0 = recorded speed)',
            0.0,
            True,
        ),
        loop=_boolean('loop', values.get('loop', False)),
        start_offset_s=_number(
            'start_offset_s',
            values.get('start_offset_s', 0.0),
            "a finite number of seconds >= 0 (and below the recording's duration)",
            0.0,
            False,
        ),
        topics=_topic_list('topics', values.get('topics')),
        publish_clock=_boolean('publish_clock', values.get('publish_clock', True)),
        clock_rate_hz=_number(
            'clock_rate_hz',
            values.get('clock_rate_hz', 100.0),
            'a finite rate in (0, 10000] Hz',
            0.0,
            True,
            10000.0,
        ),
        wait_for_topics=_topic_list('wait_for_topics', values.get('wait_for_topics')) or (),
        delay_s=_number(
            'delay_s', values.get('delay_s', 0.0), 'a finite number of seconds >= 0', 0.0, False
        ),
        replay_commands=_boolean('replay_commands', values.get('replay_commands', False)),
    )


# ---- recording and schedule (no ROS) ------------------------------------------------------------
def load_recording(path: str | Path) -> Recording:
    """
    Return every message of the file as raw CDR, sorted by log time.

    BagReadError for a missing file, a non-MCAP file or a non-ros2 one; ConfigError for a file
    without messages.
    """
    info = BagInfo(Path(path))
    messages = [
        (m.log_time_ns, m.topic, bytes(m.msg)) for m in iter_bag(path, info=info, decode=False)
    ]
    if not messages:
        damage = info.damage_report()
        raise ConfigError(
            f'bag={str(path)!r} rejected: it holds no readable messages'
            f'{" (" + damage + ")" if damage else ""}; allowed: a recording with messages'
        )
    messages.sort(key=lambda m: m[0])
    return Recording(
        Path(path),
        messages,
        dict(info.topics),
        messages[0][0],
        messages[-1][0],
        info.truncated,
        info.damage_report(),
    )


def is_command_topic(topic: str) -> bool:
    """
    Tell whether `topic` is a simulator command topic (any namespace).

    Those are replayed only on request.
    """
    from pulsejet_sim.core.topics import COMMAND_TOPICS, TOPIC_CMD_COMMAND

    return any(topic.endswith('/' + name) for name in COMMAND_TOPICS + (TOPIC_CMD_COMMAND,))


def build_schedule(rec: Recording, cfg: ReplayConfig) -> Schedule:
    """Build the events of one pass, in publication order, with their log-time offsets."""
    if cfg.topics is not None:
        unknown = [t for t in cfg.topics if t not in rec.topics]
        if unknown:
            raise ConfigError(
                f'topics entry {unknown[0]!r} is not in {str(rec.path)!r}; allowed: '
                f'{", ".join(sorted(rec.topics))}'
            )
    duration_s = (rec.last_ns - rec.first_ns) * 1e-9
    offset_ns = int(round(cfg.start_offset_s * 1e9))
    if cfg.start_offset_s > 0 and offset_ns > rec.last_ns - rec.first_ns:
        raise ConfigError(
            f'start_offset_s={cfg.start_offset_s!r} rejected; allowed: a number of seconds '
            f">= 0 and <= the recording's duration {duration_s:.6g} s"
        )
    base = rec.first_ns + offset_ns
    recorded_clock = rec.has_clock

    def wanted(topic: str) -> bool:
        if topic == CLOCK_TOPIC:
            return cfg.publish_clock
        if cfg.topics is not None:
            return topic in cfg.topics
        return cfg.replay_commands or not is_command_topic(topic)

    events = [
        Event(ns - base, topic, payload)
        for ns, topic, payload in rec.messages
        if ns >= base and wanted(topic)
    ]
    duration_ns = rec.last_ns - base
    generated = cfg.publish_clock and not recorded_clock
    if generated:
        # one tick per 1/clock_rate_hz of wall time, i.e. every rate/clock_rate_hz of log time,
        # and one at the very end, so the clock reaches the last log time
        period_ns = max(1, int(round(cfg.rate / cfg.clock_rate_hz * 1e9)))
        if duration_ns // period_ns > MAX_CLOCK_TICKS:
            raise ConfigError(
                f'clock_rate_hz={cfg.clock_rate_hz!r} rejected for {str(rec.path)!r}: its log '
                'times span '
                f'{duration_ns * 1e-9:.6g} s, which needs {duration_ns // period_ns} generated '
                '/clock '
                f'ticks; allowed: at most {MAX_CLOCK_TICKS} (lower clock_rate_hz, '
                'publish_clock:=false, '
                'or repair/trim a file with a damaged log time)'
            )
        ticks = list(range(0, duration_ns + 1, period_ns))
        if not ticks or ticks[-1] != duration_ns:
            ticks.append(duration_ns)
        # a tick before the messages of its instant: consumers see time >= their stamps
        clock_events = [Event(t, CLOCK_TOPIC, None, base + t) for t in ticks]
        merged = sorted(
            [(e.offset_ns, 0, i, e) for i, e in enumerate(clock_events)]
            + [(e.offset_ns, 1, i, e) for i, e in enumerate(events)],
            key=lambda x: x[:3],
        )
        events = [x[3] for x in merged]
    topics = {e.topic: rec.topics.get(e.topic, CLOCK_TYPE) for e in events}
    if not events:
        raise ConfigError(
            f'nothing to play from {str(rec.path)!r} with topics={list(cfg.topics or [])!r}, '
            f'start_offset_s={cfg.start_offset_s!r}, publish_clock={cfg.publish_clock!r}'
        )
    return Schedule(events, duration_ns, base, topics, generated)


def message_class(type_name: str) -> type:
    """
    Return the generated Python class of 'pkg/msg/Type'.

    rosidl_runtime_py when installed, else importlib.
    """
    try:
        from rosidl_runtime_py.utilities import get_message

        return get_message(type_name)
    except ImportError:
        pass
    except (AttributeError, ValueError, ModuleNotFoundError):
        raise ValueError(f'message type {type_name!r} is not installed') from None
    parts = type_name.split('/')
    if len(parts) != 3:
        raise ValueError(f'message type {type_name!r} is not of the form pkg/msg/Type')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.{parts[1]}'), parts[2])
    except (ImportError, AttributeError):
        raise ValueError(
            f'message type {type_name!r} is not installed '
            f'(no class {parts[2]} in Python module {parts[0]}.{parts[1]})'
        ) from None


# ---- player (ROS) -------------------------------------------------------------------------------
class Player:
    """Publishes a Schedule on `node` at its recorded pace; run() returns when done or stopped."""

    def __init__(self, node: Any, schedule: Schedule, cfg: ReplayConfig, log=print) -> None:
        from pulsejet_sim.ros.messages import reliable_qos
        from rosgraph_msgs.msg import Clock

        self._Clock = Clock
        self.node = node
        self.schedule = schedule
        self.cfg = cfg
        self.log = log
        self.publishers: dict[str, Any] = {}
        skipped = set()
        for topic, type_name in schedule.topics.items():
            try:
                cls = message_class(type_name)
            except ValueError as err:
                log(f'replay: warning: {topic} skipped: {err}', file=sys.stderr)
                skipped.add(topic)
                continue
            # reliable (/clock too: it matches reliable and best-effort subscriptions)
            self.publishers[topic] = node.create_publisher(
                cls, topic, reliable_qos(topic, QOS_DEPTH)
            )
        if skipped:
            schedule.events = [e for e in schedule.events if e.topic not in skipped]
        missing = [t for t in cfg.wait_for_topics if t not in self.publishers]
        if missing:
            raise ConfigError(
                f'wait_for_topics entry {missing[0]!r} is not replayed; allowed: '
                f'{", ".join(sorted(self.publishers))}'
            )
        self.counts: dict[str, int] = dict.fromkeys(self.publishers, 0)
        self.passes = 0
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def sleep_until(self, target: float) -> bool:
        """
        Sleep until time.monotonic() >= target; False when stopped.

        Sleeps in chunks, so a stop request is seen within MAX_SLEEP_S.
        """
        while not self._stop.is_set():
            remaining = target - time.monotonic()
            if remaining <= 0:
                return True
            time.sleep(min(remaining, MAX_SLEEP_S))
        return False

    def wait_for_subscribers(self) -> bool:
        if not self.cfg.wait_for_topics:
            return True
        self.log(
            f'replay: waiting for subscribers on {", ".join(self.cfg.wait_for_topics)}', flush=True
        )
        while not self._stop.is_set():
            if all(
                self.publishers[t].get_subscription_count() > 0 for t in self.cfg.wait_for_topics
            ):
                return True
            time.sleep(0.02)
        return False

    def play_pass(self, start: float) -> bool:
        """One pass of the schedule from wall time `start`; False when stopped."""
        rate = self.cfg.rate
        publishers = self.publishers
        for event in self.schedule.events:
            if not self.sleep_until(start + event.offset_ns * 1e-9 / rate):
                return False
            pub = publishers[event.topic]
            if event.payload is None:
                msg = self._Clock()
                msg.clock.sec, msg.clock.nanosec = divmod(event.clock_ns, 1_000_000_000)
                pub.publish(msg)
            else:
                pub.publish(event.payload)
            self.counts[event.topic] += 1
        return True

    def run(self) -> bool:
        """Play (and loop); True when the end was reached, False when stopped."""
        if not self.wait_for_subscribers():
            return False
        if self.cfg.delay_s > 0 and not self.sleep_until(time.monotonic() + self.cfg.delay_s):
            return False
        pass_s = max(
            self.schedule.wall_duration_s(self.cfg.rate), MIN_PASS_S if self.cfg.loop else 0.0
        )
        start = time.monotonic()
        while True:
            if not self.play_pass(start):
                return False
            self.passes += 1
            if not self.cfg.loop:
                return True
            start += pass_s  # the next pass starts where this one ends: no drift across passes
            if not self.sleep_until(start):
                return False
            if CLOCK_TOPIC in self.publishers:
                self.log(
                    f'replay: pass {self.passes + 1}: restarting; /clock jumps back to '
                    f'{self.schedule.base_ns * 1e-9:.9f} s',
                    flush=True,
                )

    def wait_acked(self, timeout_s: float = ACK_TIMEOUT_S) -> None:
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        for pub in self.publishers.values():
            remaining = max(0.0, deadline - time.monotonic())
            try:
                pub.wait_for_all_acked(Duration(seconds=remaining))
            except Exception:  # best effort at exit
                pass


def read_parameters(node: Any) -> dict[str, Any]:
    """
    Return the parameter values (overrides over defaults), checked and declared.

    Checked by check_config (ConfigError names a bad or unknown one), then declared with their
    descriptors (parameter_specs).
    """
    specs = parameter_specs()
    overrides = getattr(node, '_parameter_overrides', {}) or {}
    values = {
        name: overrides[name].value if name in overrides else spec.default
        for name, spec in specs.items()
    }
    for name in overrides:  # a misspelt -p name:=value would otherwise be ignored silently
        if name not in values and name != 'use_sim_time':
            values[name] = overrides[name].value
    check_config(
        values
    )  # before declaring: the error is ours, naming the value, not rclpy's range text
    for name, spec in specs.items():
        node.declare_parameter(name, spec.default, spec.descriptor())
    return {**values, **{name: node.get_parameter(name).value for name in specs}}


def main(args: Sequence[str] | None = None) -> int:
    from pulsejet_sim.ros.executor import make_executor
    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    # Our own SIGINT/SIGTERM handlers: stop at the next sleep chunk, then clean up.
    rclpy.init(
        args=list(args) if args is not None else None,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    node = Node('replay')

    def fail(message: str) -> int:
        print(f'replay: error: {message}', file=sys.stderr, flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2

    try:
        cfg = check_config(read_parameters(node))
        recording = load_recording(cfg.bag)
        schedule = build_schedule(recording, cfg)
        player = Player(node, schedule, cfg)
    except BagReadError as err:
        return fail(f'bag {err}')
    except ConfigError as err:
        return fail(str(err))

    previous = {}

    def on_signal(signum: int, frame: Any) -> None:
        if player.stopped:  # second signal: give up on the clean exit
            raise KeyboardInterrupt
        player.stop()

    for s in (signal.SIGINT, signal.SIGTERM):
        previous[s] = signal.signal(s, on_signal)
    # Serve the node's services (parameters) while playing. spin_once in our own loop, joined
    # before the executor is shut down: Executor.shutdown() in rclpy 7.1 does not wait for a spin()
    # running in another thread, and destroying its guard condition under it aborts the process at
    # exit.
    executor = make_executor()
    executor.add_node(node)
    spinning = threading.Event()
    spinning.set()

    def spin() -> None:
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.1)

    spinner = threading.Thread(target=spin, name='replay-executor', daemon=True)
    spinner.start()
    clock_note = (
        'recorded /clock'
        if recording.has_clock and cfg.publish_clock
        else (
            'generated /clock at %g Hz' % cfg.clock_rate_hz
            if schedule.generated_clock
            else 'no /clock'
        )
    )
    if recording.truncated or recording.damage:
        print(
            f'replay: warning: {cfg.bag} is damaged '
            f'({recording.damage or "cut short, writer killed"}); '
            'playing what is complete',
            file=sys.stderr,
            flush=True,
        )
    print(
        f'replay: playing {cfg.bag}: {len(schedule.events)} messages on {len(player.publishers)} '
        'topics, '
        f'{schedule.duration_ns * 1e-9:.3f} s at rate {cfg.rate:g} '
        f'({schedule.wall_duration_s(cfg.rate):.3f} s), '
        f'{clock_note}{", looping" if cfg.loop else ""}',
        flush=True,
    )
    wall = time.monotonic()
    finished = False
    try:
        finished = player.run()
    except KeyboardInterrupt:
        pass
    finally:
        wall = time.monotonic() - wall
        player.wait_acked()
        spinning.clear()
        spinner.join()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
    total = sum(player.counts.values())
    print(
        f'replay: {"finished" if finished else "stopped"}: published {total} messages in '
        f'{wall:.3f} s ({passes_phrase(player.passes, finished, total)})',
        flush=True,
    )
    return 0


def passes_phrase(complete: int, finished: bool, published: int) -> str:
    """
    Say how far the replay got: complete passes, and the pass a stop interrupted.

    '1 pass', '3 passes'; stopped: 'stopped before playing' (nothing published: still waiting or
    in delay_s), 'in pass 1', 'in pass 3, 2 complete'.
    """
    if finished:
        return f'{complete} pass{"es" if complete != 1 else ""}'
    if complete == 0 and published == 0:
        return 'stopped before playing'
    return f'in pass {complete + 1}' + (f', {complete} complete' if complete else '')


if __name__ == '__main__':
    sys.exit(main())
