"""
Hardware-in-the-loop style benchmark: an external controller closes a loop on sim_node's state.

    .venv/bin/python -m benchmarks.performance.bench_hil [--seconds 60] [--rates 100 500 1000]
                                             [--real-time-factor 1] [--no-write]
                                             [--sim-executor single|events] [--atomic]

For each state rate (sim_node `publish_rate_hz`), sim_node runs as a subprocess (real_time pacing)
in an isolated ROS domain with localhost discovery, and this process is the controller: a
bang-bang on the cavity volume (pump on, valve shut until volume > V1; then pump off, valve open
until volume < V0), decided in the pulsejet/volume callback and published at once. Measured from
receive times (time.monotonic, one clock for both processes):
  - period jitter of the state stream: p50 / p99 of |receive period - 1/rate| of /clock,
  - command-to-effect latency: from the wall time a command is published to the receipt of the
    first state computed with it (the first /clock after the pulsejet/applied_command showing the
    whole command, i.e. the end of the first physics batch that held it): p50 / p99, and to the
    receipt of that applied_command,
  - the real-time factor held over the measured window (simulated s / wall s of /clock),
  - sim_node's own physics cost per step (mean of its /diagnostics),
  - the machine's floor over the same window: the wake-up lateness p99 of a process that only
    sleeps to a grid at the state rate (wake_floor.py); a latency needs two such wake-ups.
--sim-executor sets sim_node's `executor` parameter; --atomic sends each command as one
pulsejet/cmd/command message instead of two Float64s. Prints a markdown table and appends it to
benchmarks/results/hil.md (newest last; header: date, nproc, python). Not a test.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
from pathlib import Path
import platform
import sys
import tempfile
import time

from benchmarks.common import append, RESULTS as RESULTS_DIR
from benchmarks.performance import wake_floor
import numpy as np

RESULTS = RESULTS_DIR / 'hil.md'
V0_M3, V1_M3 = 1.6e-3, 2.4e-3  # bang-bang band on the cavity volume
PUMP_M3_S = 2.5e-3
FILL = (PUMP_M3_S, 0.0)  # (pump flow, valve opening)
JET = (0.0, 1.0)
PUMP_AND_VALVE = ('pump_flow_m3_s', 'valve_opening')  # the actuators a mode sets
TITLE = '# HIL benchmark (external bang-bang controller on sim_node state)\n'
LEGEND = (
    'jitter: |receive period of /clock - 1/rate|. latency: wall time from the publication of'
    ' a command to the receipt of the first state computed with it (first /clock after the'
    ' pulsejet/applied_command showing it), and to the receipt of that applied_command.'
    ' physics cost: sim_node /diagnostics physics_us_per_step, mean. The controller decides on'
    ' the state just received, i.e. right after a tick, so the command waits almost one'
    ' publication period for the next tick: at 100 Hz the latency is about one period plus'
    ' transport; at 500 and 1000 Hz transport and the queue of state messages both processes'
    ' work through dominate. The cost per step grows at high rates because the batches get'
    ' short (10 steps at 1000 Hz, 100 at 100 Hz) and the per-call overhead of Simulation.step'
    ' is shared by fewer steps; on 2 cores the 1000 Hz stream is bounded by Python/DDS'
    ' publishing in sim_node and receiving in the controller, not by the physics. machine'
    ' floor: a process that only sleeps to a grid at the state rate, beside the measurement'
    ' (benchmarks/performance/wake_floor.py): how late it woke (p99) and its period jitter'
    ' (p99); a command-to-state latency takes at least two wake-ups (sim_node on the command, the'
    ' controller on the state), so its tail is no shorter than the floor.\n'
)


def run_rate(
    rate_hz: float,
    seconds: float,
    rtf: float,
    scene: str,
    domain: int,
    log_dir: Path,
    atomic: bool = False,
    sim_executor: str = 'single',
) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from pulsejet_sim.core.model_io import Command
    from pulsejet_sim.ros import messages
    from pulsejet_sim.ros.executor import make_executor
    from pulsejet_sim.ros.launching import (
        discover_localhost_only,
        isolated_environment,
        NodeProcess,
    )
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    env = isolated_environment(domain)
    discover_localhost_only()  # this process's participant too
    sim = NodeProcess(
        'pulsejet_sim.ros.sim_node',
        {
            'scene': scene,
            'pacing': 'real_time',
            'real_time_factor': float(rtf),
            'publish_rate_hz': float(rate_hz),
            'start_paused': True,
            'executor': sim_executor,
            # each state sent once computed, as hardware in the loop wants (docs/user/ros.md)
            'publish_delay_periods': 0.0,
        },
        log_dir / f'sim_node.{int(rate_hz)}.log',
        env,
    )
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('bench_hil_controller', context=context)
    executor = make_executor(context=context)
    executor.add_node(node)
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

    st = {'measuring': False, 'mode': None, 'pending': None, 'volume': None, 'time_s': 0.0}
    clock_recv, clock_time = [], []
    latency_state, latency_applied = [], []
    physics_us = []
    if atomic:  # one message sets pump and valve at the same step
        pubs = {'command': node.create_publisher(JointState, messages.TOPIC_CMD_COMMAND, qos)}
    else:
        pubs = {
            'pump': node.create_publisher(Float64, messages.TOPIC_CMD_PUMP_FLOW, qos),
            'valve': node.create_publisher(Float64, messages.TOPIC_CMD_VALVE, qos),
        }

    def command(mode):
        st['mode'] = mode
        if atomic:  # pump and valve only: a cable the scene may have is left as it is
            pubs['command'].publish(
                messages.command_message(Command(*mode), st['time_s'], fields=PUMP_AND_VALVE)
            )
        else:
            pubs['valve'].publish(Float64(data=mode[1]))
            pubs['pump'].publish(Float64(data=mode[0]))
        # pending: (target, publication wall time, applied stamp once seen, applied receipt)
        st['pending'] = [mode, time.monotonic(), None, None]

    def on_volume(msg):
        v = msg.data
        st['volume'] = v
        if st['mode'] is None:
            return
        if st['mode'] == FILL and v > V1_M3:
            command(JET)
        elif st['mode'] == JET and v < V0_M3:
            command(FILL)

    def on_applied(msg):
        p = st['pending']
        if p is None or p[2] is not None:
            return
        t, cmd = messages.command_from_applied(msg)
        if (cmd.pump_flow_m3_s, cmd.valve_opening) == p[0]:
            p[2], p[3] = t, time.monotonic()

    def on_clock(msg):
        now = time.monotonic()
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        st['time_s'] = t
        if st['measuring']:
            clock_recv.append(now)
            clock_time.append(t)
        p = st['pending']
        if p is not None and p[2] is not None and t > p[2]:
            if st['measuring']:
                latency_state.append(now - p[1])
                latency_applied.append(p[3] - p[1])
            st['pending'] = None

    def on_diagnostics(msg):
        for s in msg.status:
            if st['measuring'] and s.name.startswith('pulsejet: ') and s.name.endswith('sim_node'):
                values = {kv.key: kv.value for kv in s.values}
                try:
                    physics_us.append(float(values.get('physics_us_per_step', 'nan')))
                except ValueError:
                    pass

    node.create_subscription(Float64, messages.TOPIC_VOLUME, on_volume, qos)
    node.create_subscription(JointState, messages.TOPIC_APPLIED_COMMAND, on_applied, qos)
    node.create_subscription(Clock, messages.TOPIC_CLOCK, on_clock, qos)
    node.create_subscription(DiagnosticArray, messages.TOPIC_DIAGNOSTICS, on_diagnostics, qos)
    from std_srvs.srv import SetBool

    pause = node.create_client(SetBool, messages.SERVICE_PAUSE)

    def spin_until(pred, timeout, what):
        end = time.monotonic() + timeout
        while not pred():
            if not sim.alive():
                raise RuntimeError(
                    f'sim_node exited with {sim.proc.returncode}:\n{sim.output()[-2000:]}'
                )
            if time.monotonic() > end:
                raise RuntimeError(f'timed out waiting for {what}:\n{sim.output()[-2000:]}')
            executor.spin_once(timeout_sec=0.01)

    try:
        spin_until(
            lambda: pause.service_is_ready()
            and all(p.get_subscription_count() > 0 for p in pubs.values())
            and st['volume'] is not None,
            120.0,
            'sim_node to start',
        )
        command(FILL)
        future = pause.call_async(SetBool.Request(data=False))
        spin_until(future.done, 30.0, 'resume')
        settle = time.monotonic() + 2.0
        spin_until(lambda: time.monotonic() > settle, 10.0, 'settling')
        floor = wake_floor.start(seconds, rate_hz)
        st['measuring'] = True
        end = time.monotonic() + seconds
        spin_until(lambda: time.monotonic() > end, seconds + 10.0, 'the measurement')
        st['measuring'] = False
        floor_result = wake_floor.result(floor)
    finally:
        code = sim.stop()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    t, s = np.array(clock_recv), np.array(clock_time)
    dev = np.abs(np.diff(t) - 1.0 / rate_hz)
    ls, la = np.array(latency_state) * 1e3, np.array(latency_applied) * 1e3

    def pct(a, q):
        return float(np.percentile(a, q)) if a.size else float('nan')

    return {
        'rate_hz': rate_hz,
        'messages': int(t.size),
        'achieved_hz': float((t.size - 1) / (t[-1] - t[0])),
        'jitter_p50_ms': pct(dev, 50) * 1e3,
        'jitter_p99_ms': pct(dev, 99) * 1e3,
        'latency_p50_ms': pct(ls, 50),
        'latency_p99_ms': pct(ls, 99),
        'latency_n': int(ls.size),
        'applied_p50_ms': pct(la, 50),
        'applied_p99_ms': pct(la, 99),
        'rtf_held': float((s[-1] - s[0]) / (t[-1] - t[0])),
        'physics_us': float(np.nanmean(physics_us)) if physics_us else float('nan'),
        'exit_code': code,
        'floor_lateness_p99_ms': floor_result['lateness_p99_ms'],
        'floor_jitter_p99_ms': floor_result['jitter_p99_ms'],
    }


def table(results: list[dict], rtf: float) -> str:
    lines = [
        (
            '| state rate | achieved | period jitter p50 / p99 | command→state latency p50 / p99'
            ' (n) | command→applied_command p50 / p99 | RTF held (requested) | physics cost |'
            ' machine floor: idle wake-up lateness p99 / period jitter p99 |'
        ),
        '|---|---|---|---|---|---|---|---|',
    ]
    for r in results:
        lines.append(
            f"| {r['rate_hz']:g} Hz | {r['achieved_hz']:.1f} Hz | {r['jitter_p50_ms']:.3f} /"
            f" {r['jitter_p99_ms']:.3f} ms | {r['latency_p50_ms']:.2f} / {r['latency_p99_ms']:.2f}"
            f" ms ({r['latency_n']}) | {r['applied_p50_ms']:.2f} / {r['applied_p99_ms']:.2f} ms |"
            f" {r['rtf_held']:.4f} ({rtf:g}) | {r['physics_us']:.2f} µs/step |"
            f" {r['floor_lateness_p99_ms']:.3f} / {r['floor_jitter_p99_ms']:.3f} ms |"
        )
    return '\n'.join(lines)


def main(argv=None) -> int:
    from pulsejet_sim.ros.executor import EXECUTOR_KINDS

    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument(
        '--seconds', type=float, default=60.0, help='wall seconds measured per rate (default 60)'
    )
    ap.add_argument(
        '--rates', type=float, nargs='+', default=[100.0, 500.0, 1000.0], help='state rates in Hz'
    )
    ap.add_argument('--real-time-factor', type=float, default=1.0)
    ap.add_argument('--scene', default='pump_cycle')
    ap.add_argument(
        '--domain-id', type=int, default=None, help='ROS domain (default 215 + pid %% 18)'
    )
    ap.add_argument('--no-write', action='store_true', help=f'do not write {RESULTS}')
    ap.add_argument(
        '--sim-executor',
        default='single',
        choices=EXECUTOR_KINDS,
        help="sim_node's executor parameter (default single, sim_node's default)",
    )
    ap.add_argument(
        '--atomic',
        action='store_true',
        help='send pump and valve in one pulsejet/cmd/command message (default: two Float64s)',
    )
    ap.add_argument('--note', default='', help='a line added under the header of the results file')
    args = ap.parse_args(argv)
    from pulsejet_sim.ros.launching import default_domain_id

    domain = default_domain_id() if args.domain_id is None else args.domain_id
    results = []
    with tempfile.TemporaryDirectory(prefix='bench-hil-') as logs:
        for rate in args.rates:
            print(f'measuring {rate:g} Hz for {args.seconds:g} s ...', flush=True)
            results.append(
                run_rate(
                    rate,
                    args.seconds,
                    args.real_time_factor,
                    args.scene,
                    domain,
                    Path(logs),
                    atomic=args.atomic,
                    sim_executor=args.sim_executor,
                )
            )
    now = _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    header = (
        f'date: {now}; machine: nproc {len(os.sched_getaffinity(0))} ({os.cpu_count()} CPUs),'
        f' {platform.machine()}, {platform.system()} {platform.release()}; python'
        f' {platform.python_version()}\ncommand:'
        ' `python -m benchmarks.performance.bench_hil --seconds'
        f' {args.seconds:g} --rates {" ".join(f"{r:g}" for r in args.rates)} --real-time-factor'
        f' {args.real_time_factor:g} --sim-executor {args.sim_executor}'
        + (' --atomic' if args.atomic else '')
        + f'`; scene {args.scene}, real_time pacing, sim_node executor {args.sim_executor},'
        f' {args.seconds:g} s measured per rate after 2 s of settling; controller: pump'
        f' {PUMP_M3_S:g} m^3/s with the valve shut until volume > {V1_M3:g} m^3, then valve open'
        f' until volume < {V0_M3:g} m^3; each command '
        + (
            'one pulsejet/cmd/command message\n'
            if args.atomic
            else 'two messages, pulsejet/cmd/valve then pulsejet/cmd/pump_flow\n'
        )
        + (f'\n{args.note}\n' if args.note else '')
    )
    section = f'\n## {now}\n\n' + header + '\n' + table(results, args.real_time_factor) + '\n'
    print(TITLE + section + '\n' + LEGEND)
    if not args.no_write:
        append(RESULTS, f'{TITLE}\nNewest last. {LEGEND}', section)
        print(f'appended to {RESULTS}')
    return 0 if all(r['exit_code'] == 0 for r in results) else 1


if __name__ == '__main__':
    sys.exit(main())
