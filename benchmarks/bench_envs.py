"""Benchmark (not a test): robot-steps per second of the vector environments.

Lumped: LumpedPumpValveVectorEnv (one numba call per control period advances all N robots) for
N = 1, 64, 1024, 16384, pump_cycle scene, dt = 1e-4 s, RK4, pump on with the valve shut then jetting;
a robot-step is one physics step (dt) of one robot; real-time factor = simulated robot-seconds per
wall second, per core (one process, one thread). Shell: ShellCableEnv in an AsyncVectorEnv with N
worker processes (shell_robot, dt = 1e-2 s). Writes benchmarks/results/envs.md.

    .venv/bin/python benchmarks/bench_envs.py [--robot-steps 4e6]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_common import header, write  # noqa: E402
from pulsejet_sim.envs import LumpedPumpValveVectorEnv, make_shell_vector_env  # noqa: E402


def bench_lumped(n: int, robot_steps: float):
    period = 0.01
    env = LumpedPumpValveVectorEnv(n, control_period_s=period, max_episode_s=1e6)
    env.reset(seed=0)
    inflate = np.tile([2.5e-3, 0.0], (n, 1))
    jet = np.tile([0.0, 1.0], (n, 1))
    env.step(inflate)   # warm-up (the kernel is compiled or loaded in __init__)
    calls = max(2, int(robot_steps / (n * env.n_steps)))
    start = time.perf_counter()
    for k in range(calls):
        env.step(inflate if (k // 50) % 2 == 0 else jet)
    wall = time.perf_counter() - start
    steps = calls * n * env.n_steps
    return steps / wall, steps * env.model.dt_s / wall, calls, wall


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
    ap.add_argument('--robot-steps', type=float, default=4e6, help='physics robot-steps per lumped case')
    args = ap.parse_args()
    rows = []
    for n in (1, 64, 1024, 16384):
        sps, rtf, calls, wall = bench_lumped(n, args.robot_steps)
        rows.append(f'| lumped, vector env (one numba call / period) | {n} | {calls} x 100 steps | {wall:.2f} | '
                    f'{sps:,.0f} | {rtf:,.0f}x |')
    for n in (1, 2):
        sps, rtf, wall = bench_shell(n)
        rows.append(f'| shell, AsyncVectorEnv ({n} worker process{"es" if n > 1 else ""}) | {n} | 20 x 5 steps | '
                    f'{wall:.2f} | {sps:,.0f} | {rtf:,.1f}x |')
    text = header('Vector environments: robot-steps per second', 'python benchmarks/bench_envs.py') + (
        'A robot-step is one physics step of one robot (lumped: RK4, dt = 1e-4 s; shell: implicit midpoint, '
        'dt = 1e-2 s). Real-time factor = simulated robot-seconds per wall second; the lumped rows run on '
        'one core (one process, one thread), the shell rows on one core per worker.\n\n'
        '| case | robots N | calls | wall s | robot-steps / s | real-time factor |\n|---|---:|---:|---:|---:|---:|\n'
        + '\n'.join(rows) + '\n')
    write('envs', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
