"""
Benchmark of the live sim_node: publication rate, period jitter and real-time factor held.

    .venv/bin/python -m benchmarks.performance.bench_sim_node [--seconds 60] [--real-time-factor 1]
                                                  [--publish-rate 0] [--scene pump_cycle]
                                                  [--controller]

Starts sim_node (and with --controller the controller_node, so the pump/valve cycle runs) as
subprocesses in an isolated ROS domain with localhost discovery, subscribes to /clock in this
process and measures:
  - achieved publication rate (messages / s of wall time),
  - period jitter: p50, p99 and max of |period - nominal period|, of the receive times
    (time.monotonic in this process) and of sim_node's send times (the DDS source timestamp each
    message carries, stamped inside sim_node's publish call),
  - the machine's floor: the same jitter of a process that only sleeps to a grid at the same rate
    (wake_floor.py, run beside the measurement),
  - real-time factor held: simulated time advanced / wall time,
  - the sim_node process's CPU use (user+sys / wall).
Prints a markdown table and appends it to benchmarks/results/sim_node.md with a header (date,
nproc, python version). Not a test.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
from pathlib import Path
import platform
import signal
import subprocess
import sys
import time

from benchmarks.common import append
from benchmarks.live import cpu_seconds
from benchmarks.performance import wake_floor
import numpy as np
from pulsejet_sim.ros.node_params import ros_value

HERE = Path(__file__).resolve().parent
RESULTS = HERE.parent / 'results' / 'sim_node.md'


def stop(proc: subprocess.Popen, timeout=10.0) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait()
    return proc.returncode


def run(
    seconds: float,
    rtf: float,
    publish_rate_hz: float,
    scene: str,
    controller: bool,
    lookahead_s: float = 0.0,
    subscribe_marker: bool = False,
    publish_delay_periods: float | None = None,
    sim_module: str = 'pulsejet_sim.ros.sim_node',
    sim_module_args: tuple = (),
) -> dict:
    """
    Measure one live run of sim_node (see the module docstring); returns the figures.

    subscribe_marker: also subscribe to pulsejet/mantle_marker as RViz or Foxglove would
    (reliable), taking the serialised bytes (raw) so this process's own decoding does not load
    the cores sim_node runs on; the markers received are counted.
    publish_delay_periods: sim_node's parameter of that name (None: its default).
    sim_module, sim_module_args: the module run as sim_node and its own arguments (trace_pacing.py
    runs sim_node with its timestamps).
    """
    from pulsejet_sim.ros.executor import make_executor
    from pulsejet_sim.scene import load_scene
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    nominal_rate = publish_rate_hz or float(load_scene(scene).publish_rate_hz or 100.0)
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(1 + (os.getpid() + 53) % 100))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    domain = int(env['ROS_DOMAIN_ID'])
    sim_cmd = [
        sys.executable,
        '-m',
        sim_module,
        *sim_module_args,
        '--ros-args',
        '-p',
        f'scene:={scene}',
        '-p',
        f'real_time_factor:={ros_value(rtf)}',
        '-p',
        f'publish_rate_hz:={ros_value(nominal_rate)}',
        '-p',
        f'lookahead_s:={ros_value(lookahead_s)}',
    ]
    if publish_delay_periods is not None:
        sim_cmd += ['-p', f'publish_delay_periods:={ros_value(float(publish_delay_periods))}']
    procs = []
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('bench_sim_node', context=context)
    # the single-threaded executor passes the message info (send times); the events executor
    # cannot (pulsejet_sim.ros.executor)
    executor = make_executor(context=context, kind='single')
    executor.add_node(node)
    recv, sent, stamps = [], [], []

    def on_clock(msg, info):
        recv.append(time.monotonic())
        sent.append(info['source_timestamp'] * 1e-9)
        stamps.append(msg.clock.sec + msg.clock.nanosec * 1e-9)

    node.create_subscription(
        Clock, '/clock', on_clock, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    )
    markers = []
    if subscribe_marker:
        from pulsejet_sim.core.topics import TOPIC_MANTLE_MARKER
        from visualization_msgs.msg import Marker

        node.create_subscription(
            Marker,
            TOPIC_MANTLE_MARKER,
            lambda data: markers.append((time.monotonic(), len(data))),
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
            raw=True,
        )
    try:
        if controller:
            procs.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        '-m',
                        'pulsejet_ctrl.controller_node',
                        '--ros-args',
                        '-p',
                        f'scene:={scene}',
                    ],
                    env=env,
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        sim = subprocess.Popen(
            sim_cmd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(sim)
        # wait for the first /clock (scene loading, JIT), then 1 s of settling, then measure
        end = time.monotonic() + 120
        while not recv and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            if sim.poll() is not None:
                raise RuntimeError(
                    f'sim_node exited with {sim.returncode}: {sim.stderr.read()[-2000:]}'
                )
        if not recv:
            raise RuntimeError('no /clock within 120 s')
        settle = time.monotonic() + 1.0
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)
        start_index = len(recv)
        floor = wake_floor.start(seconds, nominal_rate)
        cpu0, wall0 = cpu_seconds(sim.pid), time.monotonic()
        end = wall0 + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            if sim.poll() is not None:
                raise RuntimeError(f'sim_node exited with {sim.returncode}')
        cpu1, wall1 = cpu_seconds(sim.pid), time.monotonic()
        floor_result = wake_floor.result(floor)
    finally:
        for p in reversed(procs):
            stop(p)
        node.destroy_node()
        rclpy.try_shutdown(context=context)

    t = np.array(recv[start_index:])
    s = np.array(stamps[start_index:])
    nominal = 1.0 / nominal_rate
    dev = np.abs(np.diff(t) - nominal)
    send_dev = np.abs(np.diff(np.array(sent[start_index:])) - nominal)
    sim_steps = np.diff(s)
    return {
        'scene': scene,
        'seconds': wall1 - wall0,
        'rtf_requested': rtf,
        'nominal_rate_hz': nominal_rate,
        'messages': len(t),
        'rate_hz': (len(t) - 1) / (t[-1] - t[0]),
        'jitter_p50_ms': float(np.percentile(dev, 50) * 1e3),
        'jitter_p99_ms': float(np.percentile(dev, 99) * 1e3),
        'jitter_max_ms': float(dev.max() * 1e3),
        'send_jitter_p50_ms': float(np.percentile(send_dev, 50) * 1e3),
        'send_jitter_p99_ms': float(np.percentile(send_dev, 99) * 1e3),
        'send_jitter_max_ms': float(send_dev.max() * 1e3),
        'floor': floor_result,
        'rtf_held': float((s[-1] - s[0]) / (t[-1] - t[0])),
        'sim_step_per_msg_ms': float(np.median(sim_steps) * 1e3),
        'cpu_percent': float(100 * (cpu1 - cpu0) / (wall1 - wall0)),
        'controller': controller,
        'lookahead_s': lookahead_s,
        'publish_delay_periods': publish_delay_periods,
        'marker_subscribed': subscribe_marker,
        'markers_received': sum(1 for t_s, _ in markers if wall0 <= t_s <= wall1),
        'marker_bytes': markers[-1][1] if markers else 0,
    }


def table(r: dict) -> str:
    rows = [
        ('scene', r['scene'] + (' (+ controller_node)' if r['controller'] else '')),
        ('wall time measured', f"{r['seconds']:.1f} s"),
        ('real-time factor requested', f"{r['rtf_requested']:g}"),
        ('sim_node lookahead_s', f"{r['lookahead_s']:g} s"),
        ('real-time factor held (sim s / wall s)', f"{r['rtf_held']:.4f}"),
        ('publication rate nominal', f"{r['nominal_rate_hz']:g} Hz"),
        (
            'publication rate achieved (/clock)',
            f"{r['rate_hz']:.2f} Hz ({r['messages']} messages)",
        ),
        ('period jitter p50 (abs(T - T0))', f"{r['jitter_p50_ms']:.3f} ms"),
        ('period jitter p99 (abs(T - T0))', f"{r['jitter_p99_ms']:.3f} ms"),
        ('period jitter max', f"{r['jitter_max_ms']:.3f} ms"),
        (
            "send period jitter p50 / p99 / max (sim_node's publish times)",
            f"{r['send_jitter_p50_ms']:.3f} / {r['send_jitter_p99_ms']:.3f} /"
            f" {r['send_jitter_max_ms']:.3f} ms",
        ),
        (
            'machine floor: idle wake-up jitter p50 / p99 / max (wake_floor.py)',
            f"{r['floor']['jitter_p50_ms']:.3f} / {r['floor']['jitter_p99_ms']:.3f} /"
            f" {r['floor']['jitter_max_ms']:.3f} ms",
        ),
        ('simulated time per message (median)', f"{r['sim_step_per_msg_ms']:.3f} ms"),
        ('sim_node CPU (user+sys / wall)', f"{r['cpu_percent']:.1f} %"),
    ]
    lines = ['| metric | value |', '|---|---|'] + [f'| {k} | {v} |' for k, v in rows]
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument(
        '--seconds', type=float, default=60.0, help='wall seconds measured (default 60)'
    )
    ap.add_argument('--real-time-factor', type=float, default=1.0)
    ap.add_argument('--publish-rate', type=float, default=0.0, help='Hz; 0 = the scene value')
    ap.add_argument('--scene', default='pump_cycle')
    ap.add_argument(
        '--controller', action='store_true', help='also run controller_node (pump/valve cycling)'
    )
    ap.add_argument(
        '--lookahead', type=float, default=0.0, help="sim_node's lookahead_s (s of simulated time)"
    )
    ap.add_argument('--no-write', action='store_true', help=f'do not append to {RESULTS}')
    args = ap.parse_args(argv)
    r = run(
        args.seconds,
        args.real_time_factor,
        args.publish_rate,
        args.scene,
        args.controller,
        args.lookahead,
    )
    now = _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    command_line = ' '.join(
        ['python -m benchmarks.performance.bench_sim_node']
        + (argv if argv is not None else sys.argv[1:])
    )
    header = (
        f'## sim_node benchmark, {now}\n\n'
        f'machine: {os.cpu_count()} CPUs (nproc {len(os.sched_getaffinity(0))}),'
        f' {platform.machine()}, '
        f'{platform.system()} {platform.release()}; python {platform.python_version()}\n'
        f'command: `{command_line}`\n'
    )
    text = header + '\n' + table(r) + '\n'
    print(text)
    if not args.no_write:
        append(
            RESULTS,
            '# sim_node live benchmarks\n\nProduced by'
            ' `benchmarks/performance/bench_sim_node.py`; newest last.\n\n',
            text,
        )
        print(f'appended to {RESULTS}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
