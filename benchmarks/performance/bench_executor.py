"""
CPU an rclpy executor spends taking a 1 kHz topic: single-threaded vs events executor.

    .venv/bin/python -m benchmarks.performance.bench_executor [--seconds 15] [--rate-hz 1000]
        [--no-write]

A publisher process sends rosgraph_msgs/Clock at the rate (best effort, as sim_node's /clock);
for each executor kind and for deserialized and raw (CDR bytes, as the recorder takes them)
subscriptions, a subscriber process spins `pulsejet_sim.ros.executor.make_executor(kind)` for a
warm-up of 3 s and then the measured seconds, and reports the messages taken and its CPU time
(user + sys, from getrusage). Writes benchmarks/results/executor.md. Not a test.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from benchmarks import common
from pulsejet_sim.ros.launching import (
    default_domain_id,
    discover_localhost_only,
    isolated_environment,
)

WARM_UP_S = 3.0
CASES = [('single', False), ('events', False), ('single', True), ('events', True)]

PUBLISHER = """
import sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
rclpy.init()
node = rclpy.create_node('bench_executor_clock')
pub = node.create_publisher(Clock, '/clock', QoSProfile(depth=10,
                            reliability=ReliabilityPolicy.BEST_EFFORT))
period, end = 1.0 / float(sys.argv[1]), time.monotonic() + float(sys.argv[2])
msg, k, t0 = Clock(), 0, time.monotonic()
while time.monotonic() < end:
    k += 1
    msg.clock.sec, msg.clock.nanosec = divmod(k * int(period * 1e9), 1_000_000_000)
    pub.publish(msg)
    delay = t0 + k * period - time.monotonic()
    if delay > 0:
        time.sleep(delay)
"""

SUBSCRIBER = """
import json, resource, sys, time
import rclpy
from pulsejet_sim.ros.executor import make_executor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
kind, raw = sys.argv[1], sys.argv[2] == 'raw'
warm_up, seconds = float(sys.argv[3]), float(sys.argv[4])
rclpy.init()
node = rclpy.create_node('bench_executor_subscriber')
taken = [0]
def on_message(msg):
    taken[0] += 1
node.create_subscription(Clock, '/clock', on_message, QoSProfile(depth=100,
                         reliability=ReliabilityPolicy.BEST_EFFORT), raw=raw)
executor = make_executor(kind=kind)
executor.add_node(node)
def spin_for(s):
    end = time.monotonic() + s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
spin_for(warm_up)
r0, n0, w0 = resource.getrusage(resource.RUSAGE_SELF), taken[0], time.monotonic()
spin_for(seconds)
r1, wall = resource.getrusage(resource.RUSAGE_SELF), time.monotonic() - w0
cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
print(json.dumps({'messages': taken[0] - n0, 'wall_s': wall, 'cpu_s': cpu}))
"""


def measure(kind: str, raw: bool, seconds: float, rate_hz: float, env: dict) -> dict:
    publisher = subprocess.Popen(
        [sys.executable, '-c', PUBLISHER, str(rate_hz), str(seconds + WARM_UP_S + 10.0)], env=env
    )
    try:
        out = subprocess.run(
            [
                sys.executable,
                '-c',
                SUBSCRIBER,
                kind,
                'raw' if raw else 'msg',
                str(WARM_UP_S),
                str(seconds),
            ],
            env=env,
            capture_output=True,
            text=True,
            timeout=seconds + WARM_UP_S + 120.0,
            check=True,
        ).stdout
    finally:
        publisher.terminate()
        publisher.wait(timeout=30)
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=float, default=15.0, help='measured seconds per case')
    ap.add_argument('--rate-hz', type=float, default=1000.0, help='publication rate')
    ap.add_argument('--no-write', action='store_true', help='print only')
    args = ap.parse_args(argv)
    if not args.seconds > 0 or not args.rate_hz > 0:
        ap.error(f'--seconds {args.seconds} / --rate-hz {args.rate_hz}: both must be > 0')
    env = isolated_environment(default_domain_id())
    discover_localhost_only()  # this process's participant too
    env.pop('PULSEJET_EXECUTOR', None)
    rows = []
    for kind, raw in CASES:
        r = measure(kind, raw, args.seconds, args.rate_hz, env)
        rows.append(
            f"| {kind} | {'raw CDR' if raw else 'deserialized'} | {r['messages']} | "
            f"{r['messages'] / r['wall_s']:.0f} | {r['cpu_s'] / r['wall_s']:.1%} | "
            f"{r['cpu_s'] / max(r['messages'], 1) * 1e6:.0f} |\n"
        )
        print(rows[-1], end='', flush=True)
        time.sleep(1.0)
    command = 'python -m benchmarks.performance.bench_executor ' + ' '.join(
        sys.argv[1:] if argv is None else argv
    )
    text = (
        common.header('rclpy executors taking a 1 kHz topic', command.strip())
        + f'A /clock publisher at {args.rate_hz:g} Hz (best effort) in its own process; one '
        f'subscriber process per row, {args.seconds:g} s measured after {WARM_UP_S:g} s. CPU is '
        "the subscriber's user + sys time over wall time.\n\n"
        '| executor | subscription | messages taken | per s | CPU | CPU per message (us) |\n'
        '|---|---|---|---|---|---|\n' + ''.join(rows)
    )
    if args.no_write:
        print(text)
    else:
        common.write('executor', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
