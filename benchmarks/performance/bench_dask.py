"""
Sweep throughput: the local process pool against a local Dask cluster.

Runs per second on the local process pool and on a local Dask cluster (dask.distributed, worker
processes, one thread each), with 1 and 2 workers. Not a test.

    .venv/bin/python -m benchmarks.performance.bench_dask  # ~2 min on 2 cores

Writes benchmarks/results/dask.md.

Two workloads: `lumped` (the escape scene, 24 runs of 3 s: short runs, so the per-run overhead of
the executor shows) and `shell` (8 runs of 1 s of paper 000's external study, consistent coupling:
~1 s of physics each). Each executor is opened, warmed up (one pass of the workload: worker start,
imports, numba cache loads) and then timed on a second pass; `first pass` includes the start-up.
The sweep's rows are checked equal between executors (all columns but wall_s).
"""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time


from benchmarks.common import cpu_model, RESULTS
from pulsejet_sim.studies.sweep import load_sweep, open_executor, run_sweep, RunSpec

OUT = RESULTS / 'dask.md'


def workloads() -> dict[str, list[RunSpec]]:
    lumped = [
        RunSpec(
            'lumped', (('k', f'{k:g}'),), 'escape', {'material': {'stiffness_n_m': float(k)}}, 3.0
        )
        for k in (
            1000,
            1200,
            1400,
            1600,
            1800,
            2000,
            2094,
            2200,
            2400,
            2600,
            2800,
            3000,
            3200,
            3400,
            3600,
            3800,
            4000,
            4200,
            4400,
            4600,
            4800,
            5000,
            5200,
            5400,
        )
    ]
    _, runs = load_sweep('paper000_study')
    shell = [
        RunSpec(r.study, r.labels, r.scene, r.overrides, 1.0, r.replace)
        for r in runs
        if r.study == 'external' and dict(r.labels)['coupling'] == 'consistent'
    ][::4][:8]
    return {'lumped': lumped, 'shell': shell}


def key(rows):
    return [(r.name, r.fault, r.simulated_s, tuple(sorted(r.metrics.items()))) for r in rows]


def main() -> int:
    loads = workloads()
    configs = [
        ('process pool', 1, {'workers': 1}),
        ('process pool', 2, {'workers': 2}),
        ('Dask LocalCluster', 1, {'dask_workers': 1}),
        ('Dask LocalCluster', 2, {'dask_workers': 2}),
    ]
    table, reference = [], {}
    for name, n, kwargs in configs:
        start = time.perf_counter()
        with open_executor(**kwargs) as executor:
            opened = time.perf_counter() - start
            for load, specs in loads.items():
                t0 = time.perf_counter()
                run_sweep(specs, executor=executor, progress=None)
                first = time.perf_counter() - t0 + (opened if load == 'lumped' else 0.0)
                t0 = time.perf_counter()
                rows = run_sweep(specs, executor=executor, progress=None)
                steady = time.perf_counter() - t0
                if load in reference:
                    assert (
                        key(rows) == reference[load]
                    ), f'{name} x{n}: rows differ from the first executor'
                else:
                    reference[load] = key(rows)
                table.append((load, len(specs), name, n, first, steady, len(specs) / steady))
                print(
                    f'{load:7s} {name:18s} {n} workers: {len(specs) / steady:7.2f} runs/s',
                    flush=True,
                )
    now = datetime.datetime.now(datetime.timezone.utc)
    lines = [
        '# Sweep throughput: process pool vs Dask LocalCluster\n',
        (
            f'{now:%Y-%m-%d %H:%M UTC}, `uname -m` {platform.machine()}, {cpu_model()},'
            f' {os.cpu_count()} cores (shared with other jobs), Python'
            f' {platform.python_version()}; command:'
            ' `.venv/bin/python -m benchmarks.performance.bench_dask`\n'
        ),
        (
            'Workloads: `lumped` = escape scene, 24 runs of 3 s simulated; `shell` = 8 runs of 1 s'
            ' of the paper 000 external study (consistent coupling, 96 elements, 0.5 ms). Timed: a'
            ' second pass on a warm executor; `first pass` includes opening the executor (worker'
            " start, imports; for `lumped` also the executor's start-up) and loading the numba"
            ' caches. The rows of every executor are equal (all columns but wall_s).\n'
        ),
        (
            '| workload | runs | executor | workers | first pass (s) | warm pass (s) | runs/s'
            ' (warm) |'
        ),
        '|---|---|---|---|---|---|---|',
    ]
    for load, runs, name, n, first, steady, rate in table:
        lines.append(
            f'| {load} | {runs} | {name} | {n} | {first:.2f} | {steady:.2f} | {rate:.2f} |'
        )
    text = '\n'.join(lines) + '\n'
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text)
    print(text)
    print(f'written to {OUT} (load average at the end: {os.getloadavg()[0]:.1f})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
