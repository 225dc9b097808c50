"""
What a viewer costs sim_node's stream: send-time jitter with the mantle Marker subscribed.

    .venv/bin/python -m benchmarks.performance.bench_viewer [--repeats 3] [--seconds 30]
        [--scene shell_robot] [--lookahead 0] [--publish-delay-periods 0.2,0] [--no-write]

Issue 26, point 5: with pulsejet/mantle_marker subscribed (as RViz or Foxglove would), sim_node's
send-time period jitter p99 on the default shell scene at 100 Hz must be at most 1.5 times that of
an idle process waking on the same 100 Hz grid in the same run. Each run is one
bench_sim_node.run (sim_node as a subprocess in an isolated domain, its send times from the DDS
source timestamps of /clock) with wake_floor.py beside it for the whole measured window; runs with
and without the Marker subscribed alternate (their order swapped every repeat), so both see the
same minutes of the shared machine. --publish-delay-periods: sim_node's parameter of that name, a
comma-separated list for an A/B comparison (every value with and without the Marker in each
repeat, the order rotated); default: the node's default. Prints a table (every run, then medians
over the repeats) and appends it to benchmarks/results/viewer.md under the figures the issue was
filed with. Not a test.
"""

from __future__ import annotations

import argparse
import datetime
import os
from pathlib import Path
import platform
import sys

from benchmarks.common import append, cpu_model
from benchmarks.performance import bench_sim_node
import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / 'results' / 'viewer.md'
#: issue 26's target: sim_node's send jitter p99 over the idle process's, Marker subscribed
RATIO_MAX = 1.5
PREAMBLE = (
    '# What a viewer costs the stream (issue 26, point 5)\n\n'
    'Produced by `benchmarks/performance/bench_viewer.py`; newest last. Target: with '
    'pulsejet/mantle_marker '
    "subscribed, sim_node's send-time period jitter p99 (shell_robot, 100 Hz) at most "
    f'{RATIO_MAX:g} x that of an idle process waking on the same grid in the same run.\n\n'
    '## Before (as issue 26 was filed: one 30 s run, the Marker built from one Python Point per '
    'vertex)\n\n'
    '| | period jitter p99 |\n|---|---|\n'
    '| velocity stream received, Marker subscribed | 10.0 ms |\n'
    "| sim_node's own send times, Marker subscribed | 9.9 ms |\n"
    '| idle process on the same 100 Hz grid, same 30 s | 3.0 ms (0.6 ms in a quieter minute) |\n'
    '\nratio send / idle: 3.3\n\n'
)


def code_version() -> str:
    """Return the commit measured (and whether the work tree differed from it)."""
    import subprocess

    def git(*args):
        return subprocess.run(
            ['git', *args], cwd=Path(__file__).resolve().parents[2], capture_output=True, text=True
        ).stdout.strip()

    commit = git('rev-parse', '--short', 'HEAD') or 'unknown'
    # the stored results change with every run: not code
    dirty = git('status', '--porcelain', '--untracked-files=no', '--', '.', ':!benchmarks/results')
    return commit + (' (with uncommitted changes)' if dirty else '')


def measure(args) -> list[dict]:
    """Run the interleaved repeats; return one result per run (with 'marker_subscribed')."""
    runs = []
    kinds = [(subscribed, delay) for delay in args.delays for subscribed in (True, False)]
    for repeat in range(args.repeats):
        shift = repeat % len(kinds)
        order = kinds[shift:] + kinds[:shift]
        if repeat % 2:
            order.reverse()
        for subscribed, delay in order:
            r = bench_sim_node.run(
                args.seconds,
                1.0,
                args.publish_rate,
                args.scene,
                False,
                args.lookahead,
                subscribe_marker=subscribed,
                publish_delay_periods=delay,
            )
            r['repeat'] = repeat + 1
            r['ratio'] = r['send_jitter_p99_ms'] / r['floor']['jitter_p99_ms']
            print(
                f"repeat {repeat + 1}, Marker {'subscribed' if subscribed else 'not subscribed'},"
                f' publish delay {delay_text(delay)}:'
                f" send p99 {r['send_jitter_p99_ms']:.3f} ms, idle p99"
                f" {r['floor']['jitter_p99_ms']:.3f} ms, ratio {r['ratio']:.2f},"
                f" {r['markers_received']} Markers",
                flush=True,
            )
            runs.append(r)
    return runs


def delay_text(delay) -> str:
    return 'default' if delay is None else f'{delay:g}'


def table(runs: list[dict], args) -> str:
    rows = []
    for r in runs:
        rows.append(
            f"| {r['repeat']} | {'yes' if r['marker_subscribed'] else 'no'} |"
            f" {delay_text(r['publish_delay_periods'])} |"
            f" {r['markers_received']} | {r['rate_hz']:.2f} |"
            f" {r['send_jitter_p50_ms']:.3f} / {r['send_jitter_p99_ms']:.3f} /"
            f" {r['send_jitter_max_ms']:.2f} |"
            f" {r['floor']['jitter_p50_ms']:.3f} / {r['floor']['jitter_p99_ms']:.3f} /"
            f" {r['floor']['jitter_max_ms']:.2f} | {r['ratio']:.2f} | {r['cpu_percent']:.0f} % |"
        )
    summary = []
    verdict = ''
    for delay in args.delays:
        for subscribed in (True, False):
            group = [
                r
                for r in runs
                if r['marker_subscribed'] == subscribed and r['publish_delay_periods'] == delay
            ]
            send = np.median([r['send_jitter_p99_ms'] for r in group])
            idle = np.median([r['floor']['jitter_p99_ms'] for r in group])
            ratio = np.median([r['ratio'] for r in group])
            summary.append(
                f"| {'yes' if subscribed else 'no'} | {delay_text(delay)} | {len(group)} |"
                f' {send:.3f} | {idle:.3f} | {ratio:.2f} |'
            )
            if subscribed:
                verdict += (
                    f'Marker subscribed, publish delay {delay_text(delay)}: median ratio'
                    f" {ratio:.2f} ({'within' if ratio <= RATIO_MAX else 'above'} the target"
                    f' {RATIO_MAX:g})\n'
                )
    marker_bytes = max((r['marker_bytes'] for r in runs), default=0)
    return (
        f'scene {args.scene}, 100 Hz unless the scene says otherwise, real time, sim_node'
        f' lookahead_s {args.lookahead:g} (its default is 0), {args.seconds:g} s measured per run,'
        f' {args.repeats} repeats; Marker: {marker_bytes} bytes per message, taken raw by the'
        ' subscriber; load average (1 min) at the end'
        f' {os.getloadavg()[0]:.2f}.\n\n'
        '| repeat | Marker subscribed | publish delay, periods | Markers received | /clock rate,'
        ' Hz | sim_node send jitter p50 / p99 / max, ms | idle process p50 / p99 / max, ms |'
        ' ratio of p99 | sim_node CPU |\n'
        '|---|---|---:|---:|---:|---:|---:|---:|---:|\n' + '\n'.join(rows) + '\n\n'
        '| Marker subscribed | publish delay, periods | runs | median send p99, ms | median idle'
        ' p99, ms | median ratio |\n|---|---:|---:|---:|---:|---:|\n' + '\n'.join(summary)
        + '\n\n' + verdict
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--repeats', type=int, default=3, help='runs of each kind (default 3)')
    ap.add_argument('--seconds', type=float, default=30.0, help='wall s measured per run')
    ap.add_argument('--scene', default='shell_robot')
    ap.add_argument('--publish-rate', type=float, default=0.0, help='Hz; 0 = the scene value')
    ap.add_argument('--lookahead', type=float, default=0.0, help="sim_node's lookahead_s")
    ap.add_argument(
        '--publish-delay-periods',
        default='',
        help="sim_node's publish_delay_periods, comma-separated to compare (default: its own)",
    )
    ap.add_argument('--no-write', action='store_true', help=f'do not append to {RESULTS}')
    args = ap.parse_args(argv)
    try:
        args.delays = [float(v) for v in args.publish_delay_periods.split(',') if v.strip()] or [
            None
        ]
    except ValueError:
        ap.error(
            f'--publish-delay-periods {args.publish_delay_periods!r} rejected; allowed: numbers'
            ' separated by commas'
        )
    if args.repeats < 1 or not args.seconds > 0:
        ap.error(
            f'--repeats {args.repeats} and --seconds {args.seconds} rejected; allowed: repeats'
            ' >= 1 and seconds > 0'
        )
    runs = measure(args)
    command = ' '.join(
        ['python -m benchmarks.performance.bench_viewer']
        + (argv if argv is not None else sys.argv[1:])
    )
    now = datetime.datetime.now(datetime.timezone.utc)
    text = (
        f'## Marker subscribed and not, interleaved, {now:%Y-%m-%d %H:%M UTC}\n\n'
        f'machine: {platform.machine()}, {cpu_model()}, {os.cpu_count()} cores (shared with other'
        f' jobs), Python {platform.python_version()}\ncommand: `.venv/bin/{command}`\n'
        f'code: {code_version()}\n\n'
        + table(runs, args)
    )
    print(text)
    if not args.no_write:
        append(RESULTS, PREAMBLE, text)
        print(f'appended to {RESULTS}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
