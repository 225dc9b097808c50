"""
The machine's own timing floor: how late a process that does nothing but wake on a grid wakes.

    .venv/bin/python -m benchmarks.performance.wake_floor [--seconds 60] [--rate-hz 100]
        [--spin-ms 0]
    .venv/bin/python -m benchmarks.performance.wake_floor --table [--seconds 30]

A Python loop sleeps to absolute deadlines k / rate (time.sleep to the next deadline, monotonic
clock) and records when it woke. It prints one JSON line: the wake-up lateness and the period
jitter |T - 1/rate| (the same measure bench_sim_node.py and bench_hil.py report for /clock),
p50 / p99 / max in ms. Run beside a live benchmark it shows what the machine alone costs: a
publication period jitter can be no better than the scheduling jitter of an idle process on the
same cores (hypervisor steal, other jobs, the kernel's timer slack). bench_sim_node.py and
bench_hil.py start it for their measured window. Not a test.

--spin-ms: sleep to each deadline less this much, then busy-wait to it (a process that spends a
core to wake on time: what is left is the machine's own stalls). --table: the sleeper and the
spinner, each alone, at 100 Hz and 1 kHz; writes benchmarks/results/wake_floor.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time


def measure(seconds: float, rate_hz: float, spin_s: float = 0.0) -> dict:
    period = 1.0 / rate_hz
    woke = []
    start = time.monotonic()
    k = 1
    while True:
        deadline = start + k * period
        if deadline - start > seconds:
            break
        delay = deadline - spin_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        while time.monotonic() < deadline:
            pass
        woke.append((deadline, time.monotonic()))
        k += 1
    import numpy as np

    deadlines, times = np.array(woke).T
    lateness = times - deadlines
    jitter = np.abs(np.diff(times) - period)

    def ms(a, q):
        return float(np.percentile(a, q) * 1e3)

    return {
        'rate_hz': rate_hz,
        'spin_ms': spin_s * 1e3,
        'wakeups': int(times.size),
        'lateness_p50_ms': ms(lateness, 50),
        'lateness_p99_ms': ms(lateness, 99),
        'lateness_max_ms': float(lateness.max() * 1e3),
        'jitter_p50_ms': ms(jitter, 50),
        'jitter_p99_ms': ms(jitter, 99),
        'jitter_max_ms': float(jitter.max() * 1e3),
    }


def start(seconds: float, rate_hz: float) -> subprocess.Popen:
    """Start the probe as a process of its own (it must not share a GIL with the measurement)."""
    return subprocess.Popen(
        [sys.executable, __file__, '--seconds', repr(seconds), '--rate-hz', repr(rate_hz)],
        stdout=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )


def result(proc: subprocess.Popen, timeout_s: float = 30.0) -> dict:
    """Wait for a probe started with `start` and return its measurement."""
    out, _ = proc.communicate(timeout=timeout_s)
    if proc.returncode != 0:
        raise RuntimeError(f'wake_floor exited with {proc.returncode}: {out[-500:]}')
    return json.loads(out.strip().splitlines()[-1])


def table(seconds: float) -> str:
    """Return the sleeper and the spinner (1 kHz: it spins the whole period), each alone."""
    import os

    cases = [(100.0, 0.0), (100.0, 0.003), (1000.0, 0.0), (1000.0, 0.001)]
    load_before = os.getloadavg()[0]
    rows = []
    for rate, spin in cases:
        r = measure(seconds, rate, spin)
        rows.append(
            f"| {rate:g} Hz | {'sleep' if spin == 0 else f'sleep, then spin {spin * 1e3:g} ms'} |"
            f" {r['wakeups']} | {r['lateness_p50_ms']:.3f} / {r['lateness_p99_ms']:.3f} /"
            f" {r['lateness_max_ms']:.2f} | {r['jitter_p50_ms']:.3f} / {r['jitter_p99_ms']:.3f} /"
            f" {r['jitter_max_ms']:.2f} |"
        )
    return (
        f'{seconds:g} s per case, one case at a time; load average (1 min) before'
        f' {load_before:.2f}, after {os.getloadavg()[0]:.2f}.\n\n'
        '| rate | wait | wake-ups | lateness p50 / p99 / max, ms | period jitter p50 / p99 / max,'
        ' ms |\n|---|---|---:|---:|---:|\n' + '\n'.join(rows) + '\n'
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--rate-hz', type=float, default=100.0)
    ap.add_argument('--spin-ms', type=float, default=0.0, help='busy-wait the last ms of a period')
    ap.add_argument('--table', action='store_true', help='write benchmarks/results/wake_floor.md')
    args = ap.parse_args(argv)
    if not (args.seconds > 0 and args.rate_hz > 0 and 0 <= args.spin_ms * args.rate_hz <= 1e3):
        ap.error(
            f'--seconds {args.seconds} and --rate-hz {args.rate_hz} must both be > 0 and'
            f' --spin-ms {args.spin_ms} between 0 and the period'
        )
    if args.table:
        from benchmarks.common import header, write

        command = ' '.join(['python -m benchmarks.performance.wake_floor'] + sys.argv[1:])
        write(
            'wake_floor',
            header("The machine's timing floor: a process that only waits for a grid", command)
            + table(args.seconds),
        )
        return 0
    print(json.dumps(measure(args.seconds, args.rate_hz, args.spin_ms * 1e-3)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
