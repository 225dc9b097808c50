"""
Soak: sim_node publishing at 1 kHz in real time with a closed-loop controller, for minutes.

    .venv/bin/python -m benchmarks.reliability.soak [--minutes 10] [--rate-hz 1000]
                            [--scene pump_cycle] [--controller routine|every_state]
                            [--warm-up-s 60] [--record] [--param-period-s 1]
                                        [--keep-dir DIR] [--no-write]

sim_node (real_time pacing, command watchdog on: 0.1 s of simulated time, safe action) and
controller_node run as processes in an isolated ROS domain with localhost discovery. The
controller closes the loop on the measured volume (its pump/valve routine inflates to a target
volume): `routine` (default) sends its commands at its own rate (50 Hz of simulated time),
`every_state` answers every published state with one atomic command (closed_loop:=true, 1000
commands a second at 1 kHz); with --record the recorder node writes /clock, the applied
commands and /diagnostics to MCAP (read back at the end with rosbags). This process
  - measures the real-time factor held (simulated s / wall s) over the whole soak after a warm-up
    minute, and over each minute: from /clock, or with --record from the stamps of sim_node's
    /diagnostics (1 Hz; then this process does not take the 1 kHz /clock itself, which would cost
    a quarter of a core of the two the system under test has) and the /clock period jitter from the
    recording (receive times at the recorder);
  - counts the watchdog trips sim_node logs (a trip with the controller alive is a missed
    command period; a 1 Hz /diagnostics sample sees only a trip that lasts until it), and reads
    its /diagnostics: wall time dropped, physics faults, commands accepted and rejected; with
    --record, for each trip, the gaps in the commands' and /clock's send and receive times
    before it (which process stalled);
  - samples every process's resident memory every 10 s; growth is measured from the end of the
    warm-up minute to the end;
  - times sim_node's parameter services the way `ros2 param dump` uses them (list_parameters,
    then get_parameters of every name), one round after another, for the whole soak.
Prints a table and writes benchmarks/results/soak.md (and soak.json, which
benchmarks/reliability/reliability_table.py turns into its soak row). Exit code 1 if a target is
missed: RTF 1.00 +- 0.01, memory growth < 5 %, no watchdog trip, no parameter round slower than
10 s. Not a test.
"""

from __future__ import annotations

import argparse
import contextlib
import json
from pathlib import Path
import re
import sys
import tempfile
import time


from benchmarks import common
from benchmarks.live import cpu_seconds, LiveClient, ParamProbe, percentile, rss_bytes
from pulsejet_sim.core import topics
from pulsejet_sim.ros.launching import (
    default_domain_id,
    discover_localhost_only,
    isolated_environment,
    NodeProcess,
)

RSS_PERIOD_S = 10.0
CONTROLLERS = {
    'routine': 'controller_node, pump/valve routine on the measured volume, commands at 50 Hz of '
    'simulated time',
    'every_state': 'controller_node closed_loop:=true, one atomic command per published state',
}
RTF_TOLERANCE = 0.01
RSS_GROWTH_LIMIT = 0.05
RECORDED_TOPICS = [
    topics.TOPIC_CLOCK,
    topics.TOPIC_APPLIED_COMMAND,
    f'{topics.TOPIC_DIAGNOSTICS}:diagnostic_msgs/msg/DiagnosticArray',
    *topics.COMMAND_TOPICS,  # the controller's commands: their send times locate a stall
]
TRIP_LINE = re.compile(r'\[WARN\] \[(\d+\.\d+)\] \[sim_node\]: command watchdog tripped')
TRIP_WINDOW_S = 0.5  # gaps are looked for in this much wall time before a trip is logged


def rtf_over(clock: list, t0_wall: float, t1_wall: float) -> float:
    """
    Return the simulated seconds per wall second between t0 and t1.

    Between the first /clock at or after t0 and the last before t1.
    """
    inside = [(w, s) for w, s in clock if t0_wall <= w <= t1_wall]
    if len(inside) < 2:
        return float('nan')
    (w0, s0), (w1, s1) = inside[0], inside[-1]
    return (s1 - s0) / (w1 - w0)


def soak(
    minutes: float,
    rate_hz: float,
    scene: str,
    record: bool,
    domain: int,
    tmp: Path,
    controller: str = 'routine',
    warm_up_s: float = 60.0,
    param_period_s: float = 1.0,
) -> dict:
    env = isolated_environment(domain)
    discover_localhost_only()  # this process's participant too
    procs = {
        'controller_node': NodeProcess(
            'pulsejet_ctrl.controller_node',
            {'scene': scene, 'closed_loop': controller == 'every_state'},
            tmp / 'controller_node.log',
            env,
        ),
        'sim_node': NodeProcess(
            'pulsejet_sim.ros.sim_node',
            {
                'scene': scene,
                'pacing': 'real_time',
                'publish_rate_hz': float(rate_hz),
                'watchdog_timeout_s': 0.1,
                'watchdog_clock': 'sim',
                'watchdog_action': 'safe',
                'diagnostics_period_s': 1.0,
                'wait_for_subscribers': 2,
            },
            tmp / 'sim_node.log',
            env,
        ),
    }
    bag = tmp / 'soak.mcap'
    if record:
        procs['recorder'] = NodeProcess(
            'pulsejet_sim.ros.recorder',
            {'output': str(bag), 'topics': RECORDED_TOPICS},
            tmp / 'recorder.log',
            env,
        )
    client = LiveClient(
        domain, 'soak_monitor', keep_clock=not record, state_topics=False, clock=not record
    )
    realtime_minus_monotonic = time.time() - time.monotonic()
    # with param_period_s 0 the probe is never polled: no dumps, and its summary counts 0 rounds
    probe = ParamProbe(client.node, period_s=param_period_s)
    rss = {name: [] for name in procs}
    try:
        client.spin_until(
            lambda: client.last_clock_s is not None and client.last_clock_s > 0.5,
            180.0,
            'sim_node to start and run',
            list(procs.values()),
        )
        start = time.monotonic()
        cpu0 = {name: cpu_seconds(p.pid) for name, p in procs.items()}
        end = start + warm_up_s + minutes * 60.0
        next_rss = start
        while time.monotonic() < end:
            client.executor.spin_once(timeout_sec=0.005)
            if param_period_s > 0:
                probe.poll()
            now = time.monotonic()
            if now >= next_rss:
                for name, p in procs.items():
                    rss[name].append((now - start, rss_bytes(p.pid)))
                next_rss += RSS_PERIOD_S
            for name, p in procs.items():
                if not p.alive():
                    raise RuntimeError(
                        f'{name} exited with {p.proc.returncode} during the soak:\n'
                        f'{p.output()[-2000:]}'
                    )
        wall = time.monotonic() - start
        cpu = {name: (cpu_seconds(p.pid) - cpu0[name]) / wall for name, p in procs.items()}
    finally:
        exit_codes = {name: p.stop() for name, p in reversed(list(procs.items()))}
        client.close()
    # sim_node logs each trip and clearance with the simulated time and the command's age: the
    # evidence of what a trip was (the 1 Hz diagnostics only say that one happened)
    watchdog_log = [
        line.strip()
        for line in procs['sim_node'].output().splitlines()
        if 'command watchdog' in line
    ]
    measured0 = start + warm_up_s
    clock = client.watch.diagnostics_clock if record else client.watch.clock_wall
    minute_rtf = [
        rtf_over(clock, measured0 + 60.0 * k, measured0 + 60.0 * (k + 1))
        for k in range(int(minutes))
    ]
    diag = [d for d in client.watch.diagnostics if d[0] >= start]
    last = diag[-1][3] if diag else {}
    trips_seen = sum(
        1 for _, _, _, values in diag if values.get('watchdog', '').startswith('tripped')
    )
    # every trip is logged; a 1 Hz diagnostics sample sees only those that last until it
    trip_wall_s = [float(m.group(1)) for line in watchdog_log if (m := TRIP_LINE.search(line))]
    start_wall = start + realtime_minus_monotonic
    trips = sum(1 for t in trip_wall_s if t >= start_wall)
    if record:  # receive times at the recorder (wall clock ns), from the end of the warm-up
        received = [ns * 1e-9 - realtime_minus_monotonic for ns in clock_receive_times_ns(bag)]
        clock_messages = len(received)
    else:
        received = [w for w, _ in clock]
        clock_messages = len(clock)
    periods = [b - a for a, b in zip(received, received[1:]) if a >= measured0]
    nominal = 1.0 / rate_hz
    growth = {}
    for name, samples in rss.items():
        after = [v for t, v in samples if t >= warm_up_s]
        growth[name] = (
            (
                (after[-1] - after[0]) / after[0],
                after[0] / 2**20,
                after[-1] / 2**20,
                max(after) / 2**20,
            )
            if len(after) >= 2
            else (float('nan'),) * 4
        )
    result = {
        'controller': controller,
        'warm_up_s': warm_up_s,
        'scene': scene,
        'rate_hz': rate_hz,
        'minutes': minutes,
        'wall_s': wall,
        'rtf': rtf_over(clock, measured0, end),
        'rtf_minute_min': min(minute_rtf, default=float('nan')),
        'rtf_minute_max': max(minute_rtf, default=float('nan')),
        'clock_messages': clock_messages,
        'clock_source': 'recorder' if record else 'monitor',
        'period_jitter_p99_ms': percentile([abs(p - nominal) for p in periods], 99) * 1e3,
        'watchdog_trips': trips,
        'watchdog_trips_in_diagnostics': trips_seen,
        'watchdog_log': watchdog_log,
        'dropped_wall_s': last.get('dropped_wall_s', '?'),
        'commands': {k: last.get(f'commands_{k}', '?') for k in ('accepted', 'rejected', 'stale')},
        'faults': last.get('fault', '?') or 'none',
        'error_diagnostics': sum(1 for d in diag if d[1] == 2),
        'rss': growth,
        'cpu': cpu,
        'exit_codes': exit_codes,
        'param_services': probe.summary(),
    }
    if record:
        result['recording'] = read_back(bag)
        result['trip_evidence'] = trip_evidence(bag, trip_wall_s)
    return result


def trip_evidence(path: Path, trips: list[float]) -> list[dict]:
    """
    Say, per trip, which process stalled: the longest gaps before it in send and receive times.

    For the controller's commands and for sim_node's /clock: the longest gap between consecutive
    send times (MCAP publish_time, the publisher's middleware time) and receive times (log_time, at
    the recorder) in the TRIP_WINDOW_S of wall time before sim_node logged the trip (`trips`: the
    wall times, s, of its trip log lines). A trip with no command-send gap near the 0.1 s timeout
    means the controller published on time and sim_node did not take the commands; a command-send
    gap means the controller did not publish. Read with the mcap library (an independent reader;
    rosbags does not expose publish_time).
    """
    from mcap.reader import make_reader

    if not trips:
        return []
    commands = {'/' + t for t in topics.COMMAND_TOPICS}
    times = {'command': ([], []), 'clock': ([], [])}  # (send, receive) in s, system clock
    try:
        with open(path, 'rb') as fh:
            for _, channel, record in make_reader(fh).iter_messages(log_time_order=False):
                key = (
                    'command'
                    if channel.topic in commands
                    else 'clock' if channel.topic == topics.TOPIC_CLOCK else None
                )
                if key is not None:
                    times[key][0].append(record.publish_time * 1e-9)
                    times[key][1].append(record.log_time * 1e-9)
    except Exception as exc:  # read_back names the failure in the table
        return [{'error': f'{type(exc).__name__}: {exc}'}]
    for send, receive in times.values():
        if send == receive:  # a recorder without send times (the events executor): say so
            send[:] = []
        send.sort()
        receive.sort()

    def longest_gap(series: list[float], end: float) -> float:
        inside = [t for t in series if end - TRIP_WINDOW_S <= t <= end]
        before = [t for t in series if t < end - TRIP_WINDOW_S][-1:]
        points = before + inside + [end]  # the gap still open when the trip was logged counts
        return max((b - a for a, b in zip(points, points[1:])), default=float('nan'))

    return [
        {
            'wall_s': t,
            **{
                f'{key}_{kind}_gap_ms': longest_gap(series, t) * 1e3
                for key, pair in times.items()
                for kind, series in zip(('send', 'receive'), pair)
            },
        }
        for t in trips
    ]


def clock_receive_times_ns(path: Path) -> list[int]:
    """Return the log (receive) times of every /clock in the recording, read with rosbags."""
    from rosbags.highlevel import AnyReader

    try:
        with AnyReader([path]) as reader:
            clock = [c for c in reader.connections if c.topic == topics.TOPIC_CLOCK]
            return sorted(t for _, t, _ in reader.messages(connections=clock))
    except Exception:  # read_back names the failure in the table
        return []


def read_back(path: Path) -> dict:
    """Messages per topic in the soak's recording, read with rosbags (an independent reader)."""
    from rosbags.highlevel import AnyReader

    counts = {}
    try:
        with AnyReader([path]) as reader:
            for connection, _, _ in reader.messages():
                counts[connection.topic] = counts.get(connection.topic, 0) + 1
    except (
        Exception
    ) as exc:  # report it in the table: the soak's verdict says the recording failed
        return {
            'error': f'{type(exc).__name__}: {exc}',
            'bytes': path.stat().st_size if path.exists() else 0,
        }
    return {'messages': counts, 'bytes': path.stat().st_size}


def verdicts(r: dict) -> list[str]:
    misses = []
    if not abs(r['rtf'] - 1.0) <= RTF_TOLERANCE:
        misses.append(f"real-time factor {r['rtf']:.4f} outside 1.00 +- {RTF_TOLERANCE}")
    for name, (g, *_rest) in r['rss'].items():
        if not g < RSS_GROWTH_LIMIT:
            misses.append(f'{name} memory grew {g:+.1%} (limit {RSS_GROWTH_LIMIT:.0%})')
    if r['watchdog_trips']:
        misses.append(f"{r['watchdog_trips']} watchdog trips logged by sim_node")
    if r['param_services']['starved']:
        misses.append(f"{r['param_services']['starved']} parameter rounds slower than 10 s")
    if r['error_diagnostics']:
        misses.append(f"{r['error_diagnostics']} ERROR diagnostics")
    if 'error' in r.get('recording', {}):
        misses.append(f"recording unreadable: {r['recording']['error']}")
    return misses


def table(r: dict) -> str:
    p = r['param_services']
    rows = [
        ('scene, publication rate', f"{r['scene']}, {r['rate_hz']:g} Hz"),
        ('controller', CONTROLLERS[r['controller']]),
        ('soak length (after the warm-up)', f"{r['minutes']:g} min (+ {r['warm_up_s']:g} s)"),
        ('real-time factor held (target 1.00 +- 0.01)', f"{r['rtf']:.4f}"),
        (
            'real-time factor, worst / best minute',
            f"{r['rtf_minute_min']:.4f} / {r['rtf_minute_max']:.4f}",
        ),
        (
            f"/clock messages received (at the {r.get('clock_source', 'monitor')}); period "
            'jitter p99',
            f"{r['clock_messages']}; {r['period_jitter_p99_ms']:.3f} ms",
        ),
        ('wall time dropped by sim_node', f"{r['dropped_wall_s']} s"),
        (
            'commands accepted / rejected / stale',
            '{accepted} / {rejected} / {stale}'.format(**r['commands']),
        ),
        (
            'watchdog trips logged by sim_node (must be 0); seen by a 1 Hz diagnostics sample',
            f"{r['watchdog_trips']}; {r.get('watchdog_trips_in_diagnostics', '?')}",
        ),
        (
            "sim_node's watchdog log (trips and clearances)",
            '<br>'.join(r.get('watchdog_log', [])) or 'none',
        ),
        ('physics fault; ERROR diagnostics', f"{r['faults']}; {r['error_diagnostics']}"),
        (
            'parameter dump rounds (list + get): p50 / p99 / max; slower than 10 s',
            f"{p['rounds']}: {p['p50_ms']:.1f} / {p['p99_ms']:.1f} / {p['max_ms']:.1f} ms; "
            f"{p['starved']}",
        ),
    ]
    for name, (g, first, last, peak) in r['rss'].items():
        rows.append(
            (
                f'{name} RSS after warm-up -> end (max), growth (limit 5 %)',
                f'{first:.1f} -> {last:.1f} MB ({peak:.1f}), {g:+.2%}',
            )
        )
    rows.append(('CPU (user+sys / wall)', ', '.join(f'{n} {c:.0%}' for n, c in r['cpu'].items())))
    rows.append(
        ('exit codes on SIGINT', ', '.join(f'{n} {c}' for n, c in r['exit_codes'].items()))
    )
    if 'recording' in r:
        rec = r['recording']
        rows.append(
            (
                'recording read back with rosbags',
                rec.get('error')
                or f"{rec['bytes'] / 2**20:.1f} MB, "
                + ', '.join(f'{t} {n}' for t, n in sorted(rec['messages'].items())),
            )
        )
    text = '| metric | value |\n|---|---|\n' + ''.join(f'| {a} | {b} |\n' for a, b in rows)
    evidence = r.get('trip_evidence') or []
    if evidence and 'error' not in evidence[0]:
        text += (
            '\nWhere each trip came from: the longest gap in the '
            f'{TRIP_WINDOW_S:g} s of wall time before it, in send times (the publisher) and '
            'receive times (the recorder), ms. A '
            'command-send gap near 100 ms: the controller did not publish; none: sim_node did '
            'not take what was published; nan: no send times recorded (the recorder needs '
            'PULSEJET_EXECUTOR=single for them).\n\n'
            '| trip logged (s of the wall clock) | command send | command receive | /clock send '
            '| /clock receive |\n|---|---|---|---|---|\n'
        )
        text += ''.join(
            f"| {e['wall_s']:.3f} | {e['command_send_gap_ms']:.1f} | "
            f"{e['command_receive_gap_ms']:.1f} | {e['clock_send_gap_ms']:.1f} | "
            f"{e['clock_receive_gap_ms']:.1f} |\n"
            for e in evidence
        )
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument(
        '--minutes', type=float, default=10.0, help='measured minutes (after a 60 s warm-up)'
    )
    ap.add_argument('--rate-hz', type=float, default=1000.0, help="sim_node's publication rate")
    ap.add_argument('--scene', default='pump_cycle')
    ap.add_argument(
        '--controller',
        choices=list(CONTROLLERS),
        default='routine',
        help='how controller_node closes the loop (default routine)',
    )
    ap.add_argument(
        '--warm-up-s',
        type=float,
        default=60.0,
        help='wall seconds before the measurement starts (default 60)',
    )
    ap.add_argument(
        '--record', action='store_true', help='also run the recorder and read its file back'
    )
    ap.add_argument(
        '--param-period-s',
        type=float,
        default=1.0,
        help='wall seconds between parameter dump rounds (0: no dumps; default 1)',
    )
    ap.add_argument(
        '--keep-dir',
        type=Path,
        help='keep the logs and the recording in this directory (default: a temporary one)',
    )
    ap.add_argument('--no-write', action='store_true', help='print only')
    args = ap.parse_args(argv)
    if not args.minutes >= 1:
        ap.error(f'--minutes {args.minutes}: must be >= 1')
    if args.keep_dir is not None:
        args.keep_dir.mkdir(parents=True, exist_ok=True)
    with (
        contextlib.nullcontext(str(args.keep_dir))
        if args.keep_dir is not None
        else tempfile.TemporaryDirectory(prefix='pulsejet_soak_')
    ) as tmp:
        r = soak(
            args.minutes,
            args.rate_hz,
            args.scene,
            args.record,
            default_domain_id(),
            Path(tmp),
            args.controller,
            args.warm_up_s,
            args.param_period_s,
        )
    command = 'python -m benchmarks.reliability.soak ' + ' '.join(
        sys.argv[1:] if argv is None else argv
    )
    misses = verdicts(r)
    text = (
        common.header('Soak of sim_node with a closed-loop controller', command.strip())
        + table(r)
        + '\nVerdict: '
        + ('every target met.' if not misses else 'MISSED: ' + '; '.join(misses))
        + '\n'
    )
    if args.no_write:
        print(text)
    else:
        common.write('soak', text)
        (common.RESULTS / 'soak.json').write_text(
            json.dumps(
                {'command': command.strip(), 'result': r, 'misses': misses}, indent=1, default=str
            )
            + '\n'
        )
    return 1 if misses else 0


if __name__ == '__main__':
    sys.exit(main())
