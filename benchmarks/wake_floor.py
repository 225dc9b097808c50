"""
The machine's own timing floor: how late a process that does nothing but wake on a grid wakes.

    .venv/bin/python benchmarks/wake_floor.py [--seconds 60] [--rate-hz 100]

A Python loop sleeps to absolute deadlines k / rate (time.sleep to the next deadline, monotonic
clock) and records when it woke. It prints one JSON line: the wake-up lateness and the period
jitter |T - 1/rate| (the same measure bench_sim_node.py and bench_hil.py report for /clock),
p50 / p99 / max in ms. Run beside a live benchmark it shows what the machine alone costs: a
publication period jitter can be no better than the scheduling jitter of an idle process on the
same cores (hypervisor steal, other jobs, the kernel's timer slack). bench_sim_node.py and
bench_hil.py start it for their measured window. Not a test.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time


def measure(seconds: float, rate_hz: float) -> dict:
    period = 1.0 / rate_hz
    woke = []
    start = time.monotonic()
    k = 1
    while True:
        deadline = start + k * period
        if deadline - start > seconds:
            break
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--rate-hz', type=float, default=100.0)
    args = ap.parse_args(argv)
    if not (args.seconds > 0 and args.rate_hz > 0):
        ap.error(f'--seconds {args.seconds} and --rate-hz {args.rate_hz} must both be > 0')
    print(json.dumps(measure(args.seconds, args.rate_hz)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
