"""
The replay node as a real subprocess in an isolated DDS domain.

Listened to from this process; plus the schedule and parameter checks without DDS.
"""

from __future__ import annotations

from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time

from geometry_msgs.msg import TwistStamped
import numpy as np
from pulsejet_sim.bag import BagInfo, BagWriter, iter_bag
from pulsejet_sim.ros.launching import isolated_environment, pick_domain_id
from pulsejet_sim.ros.replay import (
    build_schedule,
    check_config,
    ConfigError,
    load_recording,
    passes_phrase,
)
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import run_scene
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

REPO = Path(__file__).resolve().parents[1]
RATE = 2.0


def domain_id(offset: int) -> int:
    """
    Return a ROS domain id, 1..100, different per test run (pid) and per test (offset).

    Offsets 20-23 of pulsejet_sim.ros.launching's (no other test file takes them).
    """
    return pick_domain_id(20 + offset)


def stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


@pytest.fixture(scope='module')
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('replay') / 'escape.mcap'
    run_scene(load_scene('escape'), 1.0, path)
    return path


@pytest.fixture(scope='module')
def recording_without_clock(recording: Path) -> Path:
    """Return the same recording minus /clock (the replay must then generate its own clock)."""
    out = recording.with_name('escape_noclock.mcap')
    info = BagInfo(recording)
    msgs = [m for m in iter_bag(recording, info=info, decode=False) if m.topic != '/clock']
    with BagWriter(out) as bag:
        for topic, type_name in info.topics.items():
            if topic != '/clock':
                bag.add_topic(topic, type_name, definition=info.definitions[type_name])
        for m in msgs:
            bag.write(m.topic, m.msg, m.log_time_ns)
    return out


class Listener:
    """Subscribes /pulsejet/velocity and /clock (reliable and best effort) in its own context."""

    def __init__(self, domain: int) -> None:
        self.context = rclpy.Context()
        rclpy.init(
            context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO
        )
        self.node = Node('replay_listener', context=self.context)
        self.velocity: list[tuple[float, TwistStamped]] = []
        self.clock: list[tuple[float, float]] = []
        self.clock_best_effort: list[float] = []
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        best_effort = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(
            TwistStamped,
            '/pulsejet/velocity',
            lambda m: self.velocity.append((time.monotonic(), m)),
            reliable,
        )
        self.node.create_subscription(
            Clock,
            '/clock',
            lambda m: self.clock.append((time.monotonic(), stamp_s(m.clock))),
            reliable,
        )
        self.node.create_subscription(
            Clock, '/clock', lambda m: self.clock_best_effort.append(stamp_s(m.clock)), best_effort
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spinning = threading.Event()
        self.spinning.set()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        # spin_once in a loop joined before shutdown (Executor.shutdown does not wait for a spin()
        # in another thread)
        while self.spinning.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.spinning.clear()
        self.thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def start_replay(domain: int, *params: str) -> subprocess.Popen:
    env = isolated_environment(domain)
    args = [sys.executable, '-m', 'pulsejet_sim.ros.replay', '--ros-args']
    for p in params:
        args += ['-p', p]
    return subprocess.Popen(
        args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def recorded_velocity(path: Path) -> tuple[list[float], list[float]]:
    msgs = [m.msg for m in iter_bag(path, topics=['/pulsejet/velocity'])]
    return [stamp_s(m.header.stamp) for m in msgs], [m.twist.linear.x for m in msgs]


@pytest.mark.timeout(60)
def test_replay_publishes_recording_with_its_timing_and_clock(recording: Path) -> None:
    domain = domain_id(0)
    listener = Listener(domain)
    try:
        proc = start_replay(
            domain,
            f'bag:={recording}',
            f'rate:={RATE}',
            "wait_for_topics:=['pulsejet/velocity', '/clock']",
            'delay_s:=0.2',
        )
        stdout, stderr = proc.communicate(timeout=40)
        time.sleep(0.2)  # acked before the replay exited; let the executor run the last callbacks
    finally:
        listener.close()
    assert proc.returncode == 0, stderr
    assert 'finished' in stdout, stdout + stderr

    stamps, values = recorded_velocity(recording)
    got = listener.velocity
    # every message, in order, with the recorded values and stamps
    assert [m.twist.linear.x for _, m in got] == values
    assert [stamp_s(m.header.stamp) for _, m in got] == stamps
    assert all(m.header.frame_id == 'pulsejet/body' for _, m in got)

    # timing: the wall duration is the recorded duration / rate, arrivals follow the stamps
    arrival = np.array([t for t, _ in got])
    arrival -= arrival[0]
    expected = (np.array(stamps) - stamps[0]) / RATE
    assert arrival[-1] == pytest.approx(expected[-1], rel=0.25)
    assert np.corrcoef(arrival, expected)[0, 1] > 0.995
    deviation = arrival - expected
    deviation -= np.median(deviation)
    assert (
        np.max(np.abs(deviation)) < 0.08
    ), f'max timing deviation {np.max(np.abs(deviation)):.3f} s'
    assert np.percentile(np.abs(deviation), 90) < 0.02  # typically < 1 ms

    # /clock: the recorded clock, in order, to the recorded end, for reliable and best-effort
    # subscribers
    recorded_clock = [stamp_s(m.msg.clock) for m in iter_bag(recording, topics=['/clock'])]
    clock = [c for _, c in listener.clock]
    assert clock == recorded_clock
    assert clock[-1] == pytest.approx(1.0)
    assert len(listener.clock_best_effort) >= 0.8 * len(recorded_clock)
    assert max(listener.clock_best_effort) == pytest.approx(1.0)


@pytest.mark.timeout(60)
def test_replay_generated_clock_topic_filter_offset_loop_and_sigint(
    recording_without_clock: Path,
) -> None:
    """
    With no /clock in the file the replay makes one; filter, offset, loop, SIGINT.

    No /clock in the file: the replay makes one from the log times; topics filter; start offset;
    looping restarts (the clock jumps back); SIGINT ends it cleanly.
    """
    domain = domain_id(1)
    listener = Listener(domain)
    try:
        proc = start_replay(
            domain,
            f'bag:={recording_without_clock}',
            'rate:=2',
            'start_offset_s:=0.5',
            "topics:=['pulsejet/velocity']",
            'loop:=true',
            "wait_for_topics:=['/pulsejet/velocity', '/clock']",
            'delay_s:=0.2',
        )
        deadline = time.monotonic() + 30
        # wait for the second pass: the clock jumps back
        while not any(b < a for (_, a), (_, b) in zip(listener.clock, listener.clock[1:])):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, 'no second pass seen'
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=10)  # a player that does not stop fails here
    finally:
        listener.close()
    assert proc.returncode == 0, stderr
    assert 'stopped' in stdout and 'generated /clock' in stdout, stdout
    # stopped during the second pass or a later one: the summary says which, not '(0 passes)'
    assert re.search(r'\(in pass ([2-9]|\d\d+), \d+ complete\)', stdout), stdout

    stamps, values = recorded_velocity(recording_without_clock)
    first_pass = [(s, v) for s, v in zip(stamps, values) if s >= 0.5 - 1e-9]
    got = [(stamp_s(m.header.stamp), m.twist.linear.x) for _, m in listener.velocity]
    assert got[: len(first_pass)] == first_pass
    clock = [c for _, c in listener.clock]
    jump = next(i for i in range(1, len(clock)) if clock[i] < clock[i - 1])
    one_pass = clock[:jump]
    assert one_pass[0] == pytest.approx(0.5) and one_pass[-1] == pytest.approx(1.0)
    assert all(b > a for a, b in zip(one_pass, one_pass[1:]))
    # 100 Hz of wall time at rate 2: a tick every 20 ms of recorded time, plus the final one
    assert 24 <= len(one_pass) <= 28
    assert clock[jump] == pytest.approx(0.5)


def test_the_summary_says_how_far_the_replay_got() -> None:
    assert passes_phrase(1, True, 40) == '1 pass'
    assert passes_phrase(3, True, 120) == '3 passes'
    assert passes_phrase(0, False, 0) == 'stopped before playing'
    assert passes_phrase(0, False, 12) == 'in pass 1'
    assert passes_phrase(2, False, 90) == 'in pass 3, 2 complete'


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    'param, value, shown',
    [
        ('rate', '-1', 'rate=-1'),
        ('rate', '.nan', 'rate=nan'),
        ('rate', '0.0', 'rate=0.0'),
        ('start_offset_s', '7.5', 'start_offset_s=7.5'),
    ],
)
def test_replay_bad_parameter_exits_2_naming_the_value(
    recording: Path, param: str, value: str, shown: str
) -> None:
    proc = start_replay(domain_id(2), f'bag:={recording}', f'{param}:={value}')
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 2, stdout + stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert (
        lines[0].startswith('replay: error:') and shown in lines[0] and 'allowed' in lines[0]
    ), lines[0]
    assert stdout == ''


@pytest.mark.timeout(30)
def test_replay_bad_files_exit_2(tmp_path: Path) -> None:
    text = tmp_path / 'notes.mcap'
    text.write_text('not a recording')
    for bag in (tmp_path / 'missing.mcap', text):
        proc = start_replay(domain_id(3), f'bag:={bag}')
        _, stderr = proc.communicate(timeout=20)
        assert proc.returncode == 2 and str(bag) in stderr and 'expected an MCAP' in stderr, stderr


# ---- no DDS -------------------------------------------------------------------------------------
def test_schedule_offsets_filter_and_generated_clock(
    recording: Path, recording_without_clock: Path
) -> None:
    rec = load_recording(recording)
    sched = build_schedule(rec, check_config({'bag': str(recording)}))
    commands = [m for m in rec.messages if '/cmd/' in m[1]]
    assert commands and not any(
        '/cmd/' in e.topic for e in sched.events
    )  # not replayed by default
    assert len(sched.events) == len(rec.messages) - len(commands) and not sched.generated_clock
    with_commands = build_schedule(
        rec, check_config({'bag': str(recording), 'replay_commands': True})
    )
    assert len(with_commands.events) == len(rec.messages)
    offsets = [e.offset_ns for e in sched.events]
    assert offsets == sorted(offsets) and offsets[0] == 0 and offsets[-1] == 1_000_000_000
    assert sched.wall_duration_s(2.0) == pytest.approx(0.5)

    cfg = check_config(
        {
            'bag': str(recording),
            'topics': ['pulsejet/velocity'],
            'publish_clock': False,
            'start_offset_s': 0.25,
        }
    )
    sched = build_schedule(rec, cfg)
    assert {e.topic for e in sched.events} == {'/pulsejet/velocity'}
    assert (
        len(sched.events) == 76
        and sched.events[0].offset_ns == 0
        and sched.duration_ns == 750_000_000
    )

    rec = load_recording(recording_without_clock)
    sched = build_schedule(
        rec, check_config({'bag': str(recording_without_clock), 'rate': 4, 'clock_rate_hz': 50})
    )
    ticks = [e for e in sched.events if e.topic == '/clock']
    assert sched.generated_clock and all(e.payload is None for e in ticks)
    # 50 Hz of wall time at rate 4: every 80 ms of recorded time; 0 .. 0.96 s, then the end, 1.0 s
    assert [e.clock_ns for e in ticks] == [80_000_000 * k for k in range(13)] + [1_000_000_000]
    # a tick comes before the messages of its instant
    first_velocity = next(i for i, e in enumerate(sched.events) if e.topic == '/pulsejet/velocity')
    assert sched.events[0].topic == '/clock' and first_velocity > 0


@pytest.mark.parametrize(
    'values, shown',
    [
        ({}, 'bag='),
        ({'bag': 'x.mcap', 'rate': -1}, 'rate=-1'),
        ({'bag': 'x.mcap', 'rate': float('nan')}, 'rate=nan'),
        ({'bag': 'x.mcap', 'rate': 'fast'}, "rate='fast'"),
        ({'bag': 'x.mcap', 'loop': 2}, 'loop=2'),
        ({'bag': 'x.mcap', 'start_offset_s': -0.1}, 'start_offset_s=-0.1'),
        ({'bag': 'x.mcap', 'clock_rate_hz': 0}, 'clock_rate_hz=0'),
        ({'bag': 'x.mcap', 'rte': 2}, "'rte'"),
        ({'bag': 'x.mcap', 'topics': [3]}, 'topics=[3]'),
    ],
)
def test_check_config_names_bad_values(values: dict, shown: str) -> None:
    with pytest.raises(ConfigError) as err:
        check_config(values)
    assert shown in str(err.value) and 'allowed' in str(err.value)
