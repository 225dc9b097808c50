"""
Benchmark (not a test): speed of the lumped model offline.

Prints a markdown table and writes it to benchmarks/results/lumped.md: physics steps per second
and real-time factor of Simulation.step for the default scene (pump_cycle) and the escape scene,
with all terms on and with every optional term off, in batches of 100 steps (a 100 Hz publication
at dt = 1e-4 s), and the offline runner end to end (including MCAP writing).
"""

from __future__ import annotations

import datetime
import os
from pathlib import Path
import platform
import sys
import tempfile
import time


from benchmarks.common import RESULTS as RESULTS_DIR
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.models.lumped.model import TERM_BITS
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import run_scene

RESULTS = RESULTS_DIR / 'lumped.md'
MINIMAL_TERMS = {name: False for name in TERM_BITS if name != 'internal_added_mass'}


def time_steps(scene_name: str, overrides=None, sim_seconds: float = 20.0, batch: int = 100):
    scene = load_scene(scene_name, overrides)
    sim = Simulation(scene.model)
    command = Command(0.0, 1.0, 0.0)
    sim.step(1, command)  # compile / load from cache outside the timing
    sim.reset()
    n = int(round(sim_seconds / scene.model.dt_s))
    start = time.perf_counter()
    done = 0
    while done < n:
        sim.step(batch, command)
        done += batch
    wall = time.perf_counter() - start
    return done / wall, done * scene.model.dt_s / wall


def main() -> int:
    rows = []
    for scene_name in ('pump_cycle', 'escape'):
        for label, overrides in (
            ('all terms', None),
            ('only m_b (others compiled out)', {'terms': MINIMAL_TERMS}),
        ):
            sps, rtf = time_steps(scene_name, overrides)
            rows.append(
                (
                    f'Simulation.step, {scene_name}, {label}, batches of 100',
                    f'{sps:,.0f}',
                    f'{rtf:,.0f}x',
                )
            )
    scene = load_scene('pump_cycle')
    run_scene(scene, 0.1)  # warm-up
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        result = run_scene(scene, 10.0, Path(tmp) / 'bench.mcap')
        wall = time.perf_counter() - start
    steps = result.sim.steps
    rows.append(
        (
            'offline runner, pump_cycle, 100 Hz MCAP output, 10 s',
            f'{steps / wall:,.0f}',
            f'{10.0 / wall:,.1f}x',
        )
    )
    header = (
        '# Lumped model'
        f' speed\n\n{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC},'
        f' {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python'
        f' {platform.python_version()}, dt = 1e-4 s, RK4, one core\n\n'
    )
    table = '| case | physics steps / s | real-time factor |\n|---|---:|---:|\n'
    table += ''.join(f'| {a} | {b} | {c} |\n' for a, b, c in rows)
    print(header + table)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(header + table)
    print(f'written to {RESULTS}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
