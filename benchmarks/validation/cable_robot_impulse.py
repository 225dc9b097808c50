"""
Numerical experiment (not a prediction): what the cable robot's measured burst asks of its thrust.

In steady periodic swimming the vehicle's speed rises within a cycle only while the jet pushes,
so its swing (max - min speed) is at most the thrust impulse per cycle J_T over the mass the
impulse accelerates, M = the vehicle's mass + the water it carries (rho V, mean cavity volume) +
its added mass (vehicle equation in pulsejet_sim/models/shell/model.py; the mantle's own momentum
swing is neglected, which the model's ratio swing / (J_T / M) below measures). The measured
figures (mean 0.135 m/s, burst 0.2 m/s, validation/cases/cable_robot_steady.yaml) have a swing of
at least burst - mean = 0.065 m/s, so they ask for J_T >= 0.065 M. Here the steady case's robot
(validation/cases/cable_robot_steady.yaml: the shipped exit) and the post-hoc sharp-edged exits
(validation/posthoc.yaml, same overrides) are run for 40 s from rest; figures over the last 8
cycles ([35, 40] s, as the case), each also at twice the elements and half the step.

    .venv/bin/python -m benchmarks.validation.cable_robot_impulse

Writes benchmarks/results/cable_robot_impulse.md.
"""

from __future__ import annotations

import sys
import time

from benchmarks import common
import numpy as np
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.routines import routine_from_scene
from pulsejet_sim.studies import validation
import yaml

CASE = 'cable_robot_steady'
MEASURED_MEAN_M_S, MEASURED_BURST_M_S = 0.135, 0.2
DURATION_S, WINDOW_START_S, CYCLES = 40.0, 35.0, 8


def variants() -> dict[str, dict]:
    """Return the runs: the case as committed and its post-hoc sharp-edged exits, by id."""
    out = {'shipped exit (the case)': {}}
    for item in yaml.safe_load(validation.POSTHOC_FILE.read_text()):
        if item['case'] == CASE:
            out[item['id']] = item['overrides']
    return out


def finer(overrides: dict) -> dict:
    """Return the overrides at twice the case scene's elements and half its step."""
    case = validation.load_case(validation.CASES_DIR / f'{CASE}.yaml')
    scene = validation._scene(case, overrides)
    return {
        **overrides,
        'mesh': {'elements': 2 * int(scene.data['mesh']['elements'])},
        'simulation': {'dt_s': scene.model.dt_s / 2},
    }


def figures(overrides: dict) -> dict:
    """Run the case's scene with `overrides`; return the window's speeds, impulse and mass."""
    case = validation.load_case(validation.CASES_DIR / f'{CASE}.yaml')
    scene = validation._scene(case, overrides)
    model = scene.model
    sim = Simulation(model)
    routine = routine_from_scene(scene.routine)
    obs = sim.observe()
    t, speed, thrust, volume = [], [], [], []
    for _ in range(int(round(DURATION_S / model.dt_s))):
        command = routine.command(sim.time_s, obs.volume_m3) if routine else sim.command
        obs = sim.step(1, command)
        t.append(sim.time_s)
        speed.append(obs.velocity_m_s)
        thrust.append(obs.thrust_n)
        volume.append(obs.volume_m3)
    t, speed, thrust, volume = map(np.asarray, (t, speed, thrust, volume))
    w = t >= WINDOW_START_S - 1e-9
    impulse = float(np.trapezoid(thrust[w], t[w])) / CYCLES
    rho = float(scene.data['fluid']['density_kg_m3'])
    mass = (
        float(scene.data['vehicle']['mass_kg']) + model.body_added_mass_kg
        + rho * float(np.mean(volume[w]))
    )
    return {
        'mean': float(np.mean(speed[w])),
        'max': float(np.max(speed[w])),
        'min': float(np.min(speed[w])),
        'impulse': impulse,
        'mass': mass,
    }


def row(name: str, f: dict, fine: dict) -> str:
    """One table row: speeds, swing, J_T, M, the bound and the finer run's differences."""
    swing = f['max'] - f['min']
    bound = f['impulse'] / f['mass']
    need = (MEASURED_BURST_M_S - MEASURED_MEAN_M_S) * f['mass']
    rel = {k: (fine[k] - f[k]) / f[k] for k in ('mean', 'max', 'impulse')}
    return (
        f"| {name} | {f['mean']:.4f} | {f['max']:.4f} | {f['min']:.4f} | "
        f"{f['max'] / f['mean']:.3f} | {1e3 * f['impulse']:.2f} | {f['mass']:.4f} | "
        f"{bound:.4f} | {swing / bound:.2f} | {1e3 * need:.1f} ({need / f['impulse']:.1f}x) | "
        f"{100 * rel['mean']:+.2f} %, {100 * rel['max']:+.2f} %, {100 * rel['impulse']:+.2f} % |"
    )


def main() -> int:
    start = time.perf_counter()
    lines = [
        '| run | mean, m/s | max, m/s | min, m/s | max / mean | J_T per cycle, mN s | M, kg | '
        'J_T / M, m/s | swing / (J_T / M) | J_T the measured swing needs, mN s | finer: mean, '
        'max, J_T |',
        '|---|---|---|---|---|---|---|---|---|---|---|',
    ]
    for name, overrides in variants().items():
        lines.append(row(name, figures(overrides), figures(finer(overrides))))
        print(lines[-1], flush=True)
    text = '\n'.join(
        [
            common.header(
                'Cable robot: the thrust impulse its measured burst needs',
                'python -m benchmarks.validation.cable_robot_impulse',
            ),
            "Numerical experiment, not a prediction (this script's docstring says why the swing "
            'is bounded by J_T / M). Steady case `cable_robot_steady` and its post-hoc '
            'sharp-edged exits (validation/posthoc.yaml), 40 s from rest, figures over [35, 40] '
            's (8 cycles). J_T: the jet thrust (observation `thrust_n`) integrated over the '
            'window, per cycle. M: vehicle mass (shell and payload, 0.335 kg) + body added mass '
            '+ rho x the mean cavity volume (the water carried). The measured figures (mean '
            '0.135 m/s, burst 0.2 m/s) have a swing of at least 0.065 m/s, so they need '
            "J_T >= 0.065 M; in brackets, that over the run's J_T. finer: the relative "
            'difference at twice the elements and half the step.',
            '',
            *lines,
            '',
            f'Wall time {time.perf_counter() - start:.0f} s.',
            '',
        ]
    )
    common.write('cable_robot_impulse', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
