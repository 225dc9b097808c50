"""
Benchmark (not a test): robot-steps per second of the vector environments.

Lumped: LumpedPumpValveVectorEnv (one numba call per control period advances all N robots) for
N = 1, 64, 1024, 16384, pump_cycle scene, dt = 1e-4 s, RK4, pump on with the valve shut then
jetting: the default (vectorised atanh, exact=False; state and pump work, losses=False), the same
with the energy ledger's losses (losses=True), and libm's atanh with the losses (exact=True, bit
for bit the single-robot env); a robot-step is one physics step (dt) of one robot; real-time
factor = simulated robot-seconds per wall second, per core (one process, one thread: the kernel
has no parallel loops).
Wall and CPU (process) time are both given: the machine is shared, and the CPU time is the better
measure of a loaded run. Shell: ShellCableEnv in an AsyncVectorEnv with N worker processes
(shell_robot, dt = 1e-2 s). Writes benchmarks/results/envs.md, keeping the previous run's table
below the new one.

    .venv/bin/python -m benchmarks.performance.bench_envs [--robot-steps 4e6] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time


from benchmarks.common import header, RESULTS, write
import numpy as np
from pulsejet_sim.envs import LumpedPumpValveVectorEnv, make_shell_vector_env


def bench_lumped(
    n: int, robot_steps: float, exact: bool = False, repeats: int = 5, losses: bool = False
):
    """
    Time `repeats` runs of `robot_steps` robot-steps each (after a warm-up call).

    Returns (fastest run, median run), each (robot-steps / wall s, real-time factor, calls, wall s,
    CPU s, robot-steps / CPU s). The fastest is timeit's figure (what the machine can do; slower
    runs are other jobs interfering), the median shows the spread.
    """
    period = 0.01
    env = LumpedPumpValveVectorEnv(
        n, control_period_s=period, max_episode_s=1e6, exact=exact, losses=losses
    )
    env.reset(seed=0)
    inflate = np.tile([2.5e-3, 0.0], (n, 1))
    jet = np.tile([0.0, 1.0], (n, 1))
    env.step(inflate)  # warm-up (the kernel is compiled or loaded in __init__)
    calls = max(2, int(robot_steps / (n * env.n_steps)))
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        cpu0 = time.process_time()
        for k in range(calls):
            env.step(inflate if (k // 50) % 2 == 0 else jet)
        wall = time.perf_counter() - start
        cpu = time.process_time() - cpu0
        steps = calls * n * env.n_steps
        assert not env.status.any(), 'a robot faulted: the benchmark would not measure the physics'
        runs.append((steps / wall, steps * env.model.dt_s / wall, calls, wall, cpu, steps / cpu))
    runs.sort(key=lambda r: r[5])
    return runs[-1], runs[len(runs) // 2]


def bench_shell(n: int, periods: int = 20):
    env = make_shell_vector_env(n)
    env.reset(seed=0)
    env.step(np.full((n, 1), 4.0))
    start = time.perf_counter()
    for k in range(periods):
        env.step(np.full((n, 1), 8.0 if k % 6 < 2 else 0.0))
    wall = time.perf_counter() - start
    env.close()
    dt = 1e-2
    steps = periods * n * 5
    return steps / wall, steps * dt / wall, wall


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        '--robot-steps', type=float, default=4e6, help='physics robot-steps per lumped run'
    )
    ap.add_argument('--repeats', type=int, default=5, help='timed runs per lumped case')
    args = ap.parse_args()
    previous = (RESULTS / 'envs.md').read_text() if (RESULTS / 'envs.md').exists() else ''
    load_before = os.getloadavg()
    rows = []
    cases = (
        (False, False, 'vectorised atanh, state and pump work (default)'),
        (False, True, 'vectorised atanh, with the ledger losses (losses=True)'),
        (True, True, 'libm atanh, with the ledger losses, bit for bit single env'),
    )
    for exact, losses, kind in cases:
        for n in (1, 64, 1024, 16384):
            best, median = bench_lumped(n, args.robot_steps, exact, args.repeats, losses)
            sps, rtf, calls, wall, cpu, sps_cpu = best
            rows.append(
                f'| lumped, vector env, {kind} | {n} | {calls} x 100 steps | {wall:.2f} | '
                f'{cpu:.2f} | {sps:,.0f} | {sps_cpu:,.0f} | {median[5]:,.0f} | {rtf:,.0f}x |'
            )
    for n in (1, 2):
        sps, rtf, wall = bench_shell(n)
        rows.append(
            f'| shell, AsyncVectorEnv ({n} worker process{"es" if n > 1 else ""}) | {n} | '
            f'20 x 5 steps | {wall:.2f} | | {sps:,.0f} | | | {rtf:,.1f}x |'
        )
    load_after = os.getloadavg()
    text = header(
        'Vector environments: robot-steps per second',
        'python -m benchmarks.performance.bench_envs',
    ) + (
        'A robot-step is one physics step of one robot (lumped: RK4, dt = 1e-4 s; shell: '
        'implicit midpoint, dt = 1e-2 s). Real-time factor = simulated robot-seconds per wall '
        'second; the lumped rows run on one core (one process, one thread; the kernel has no '
        'parallel loops), the shell rows on one core per worker. '
        "CPU s: the process's CPU time (the shell rows: the workers' is not counted). "
        f'Lumped rows: the fastest of {args.repeats} timed runs (as timeit reports: slower runs'
        ' are other jobs on the shared machine); the median run is given by its robot-steps /'
        ' CPU s. '
        f'Load average (1 min) before {load_before[0]:.2f}, after {load_after[0]:.2f} on '
        f'{os.cpu_count()} cores'
        + (
            ': measured on a loaded machine, the wall figures are low.'
            if max(load_before[0], load_after[0]) > 1.0
            else '.'
        )
        + '\n\n'
        '| case | robots N | calls | wall s | CPU s | robot-steps / wall s | robot-steps / CPU s '
        '| robot-steps / CPU s, median run | real-time factor |\n'
        '|---|---:|---:|---:|---:|---:|---:|---:|---:|\n' + '\n'.join(rows) + '\n'
    )
    if previous:
        # keep the previous run's table (not its own previous one) for comparison
        prev = previous.split('\n## Previous run', 1)[0].split('\n', 1)[-1].strip()
        text += '\n## Previous run\n\n' + prev + '\n'
    write('envs', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
