"""
Numerical experiment (not a prediction): what the cable robot's measured burst asks of its thrust.

The vehicle's equation (pulsejet_sim/models/shell/model.py) is ``M U' = T - D - ram + F_ring``
with ``M`` = vehicle mass + body added mass + the water carried, rho V. While the speed rises,
drag and the refill's ram force only hold it back, so over a steady cycle the swing (max - min
speed) is at most ``(J_T + J_ring+) / M_min``: the thrust impulse per cycle, plus what the ring
force pushes forward (the mantle's own momentum and its nodes' added mass), over the least mass
carried in the cycle. The ring's forward push is not observed here; the model's ratio
swing / (J_T / M_min) below shows how far inside the bound the runs stay. The measured figures
(mean 0.135 m/s, burst 0.2 m/s, validation/cases/cable_robot_steady.yaml) swing by at least
burst - mean = 0.065 m/s, so as one steady cycle they need ``J_T >= 0.065 M_min`` (less the
ring's push). In a steady cycle J_T is also what body drag, ram and the rest (the wall's
tangential drag, reaching the vehicle through the ring) take per cycle; at the measured mean
the drags would take (0.135 / mean)^2 times the run's (quadratic drag) and the ram 0.135 / mean
times (the same stroke drawn in at a higher speed). Runs: the steady case as committed and its
post-hoc sharp-edged exits (validation/posthoc.yaml, same overrides), 40 s from rest; figures
over the last 8 cycles ([35, 40] s, as the case), each also at twice the elements and half the
step.

    .venv/bin/python -m benchmarks.validation.cable_robot_impulse

Writes benchmarks/results/cable_robot_impulse.md.
"""

from __future__ import annotations

import sys
import time

from benchmarks import common
import numpy as np
from pulsejet_sim.studies import validation
import yaml

CASE = 'cable_robot_steady'


def variants() -> dict[str, dict]:
    """Return the runs: the case as committed and its post-hoc sharp-edged exits, by id."""
    out = {'shipped exit (the case)': {}}
    for item in yaml.safe_load(validation.POSTHOC_FILE.read_text()):
        if item['case'] == CASE:
            out[item['id']] = item['overrides']
    return out


def finer(overrides: dict, run: dict) -> dict:
    """Return the overrides at twice the run's elements and half its step."""
    return {
        **overrides,
        'mesh': {'elements': 2 * run['elements']},
        'simulation': {'dt_s': run['dt_s'] / 2},
    }


def figures(case: dict, overrides: dict) -> dict:
    """Run the case's scene with `overrides` as the case runs it; return the window's figures."""
    scene = validation.case_scene(case, overrides)
    trace = validation.run_trace(scene, float(case['run']['duration_s']), scene.model.dt_s)
    assert trace.fault is None, trace.fault
    start, _, cycles = validation.window_of(case, scene, float(trace.t[-1]))
    t, speed, volume = trace.t, trace.v, trace.volume
    rho = float(scene.data['fluid']['density_kg_m3'])
    # the refill's ram force rho V' U (V' > 0: water drawn in), V' from the sampled volumes
    ram = rho * np.maximum(np.gradient(volume, t), 0.0) * speed
    w = t >= start - 1e-9

    def per_cycle(force):
        return float(np.trapezoid(force[w], t[w])) / cycles

    impulse, ram_impulse = per_cycle(trace.thrust), per_cycle(ram)
    body_drag = per_cycle(-trace.drag)
    body = float(scene.data['vehicle']['mass_kg']) + scene.model.body_added_mass_kg
    return {
        'mean': float(np.mean(speed[w])),
        'max': float(np.max(speed[w])),
        'min': float(np.min(speed[w])),
        'impulse': impulse,
        'drag': body_drag,
        'ram': ram_impulse,
        'rest': impulse - body_drag - ram_impulse,
        'mass_min': body + rho * float(np.min(volume[w])),
        'elements': int(scene.data['mesh']['elements']),
        'dt_s': scene.model.dt_s,
    }


def row(name: str, f: dict, fine: dict, measured: dict) -> str:
    """One table row: speeds, the impulses per cycle, the bound and the finer run's differences."""
    swing = f['max'] - f['min']
    bound = f['impulse'] / f['mass_min']
    burst_needs = (measured['burst_speed'] - measured['mean_speed']) * f['mass_min']
    scale = measured['mean_speed'] / f['mean']
    mean_takes = (f['drag'] + f['rest']) * scale**2 + f['ram'] * scale
    rel = {k: (fine[k] - f[k]) / f[k] for k in ('mean', 'max', 'impulse')}
    return (
        f"| {name} | {f['mean']:.4f} | {f['max']:.4f} | {f['min']:.4f} | "
        f"{f['max'] / f['mean']:.3f} | {1e3 * f['impulse']:.2f} | {1e3 * f['drag']:.2f}, "
        f"{1e3 * f['ram']:.2f}, {1e3 * f['rest']:.2f} | {f['mass_min']:.4f} | "
        f'{swing / bound:.2f} | '
        f"{1e3 * burst_needs:.1f} ({burst_needs / f['impulse']:.1f}x) | {1e3 * mean_takes:.1f} | "
        f"{100 * rel['mean']:+.2f} %, {100 * rel['max']:+.2f} %, {100 * rel['impulse']:+.2f} % |"
    )


def main() -> int:
    start = time.perf_counter()
    lines = [
        '| run | mean, m/s | max, m/s | min, m/s | max / mean | J_T per cycle, mN s | body drag, '
        'ram, rest, mN s | M_min, kg | swing / (J_T / M_min) | J_T the measured swing needs, '
        'mN s | J_T the measured mean takes, mN s | finer: mean, max, J_T |',
        '|---|---|---|---|---|---|---|---|---|---|---|---|',
    ]
    case = validation.load_case(validation.CASES_DIR / f'{CASE}.yaml')
    measured = {f['id']: f['measured'] for f in case['figures']}
    for name, overrides in variants().items():
        run = figures(case, overrides)
        fine = figures(case, finer(overrides, run))
        lines.append(row(name, run, fine, measured))
        print(lines[-1], flush=True)
    text = '\n'.join(
        [
            common.header(
                'Cable robot: the thrust impulse its measured burst needs',
                'python -m benchmarks.validation.cable_robot_impulse',
            ),
            "Numerical experiment, not a prediction (this script's docstring gives the bound and "
            'its terms). Steady case `cable_robot_steady` and its post-hoc sharp-edged exits '
            '(validation/posthoc.yaml), 40 s from rest, figures over [35, 40] s (8 cycles). J_T: '
            'the jet thrust (observation `thrust_n`) integrated over the window, per cycle; split '
            "into the body drag (`drag_n`), the refill ram force rho V' U and the rest (the "
            "wall's tangential drag through the ring). M_min: vehicle mass (shell and payload, "
            '0.335 kg) + body added mass + rho x the smallest cavity volume in the window. The '
            'measured figures (mean 0.135 m/s, burst 0.2 m/s) swing by at least 0.065 m/s, so '
            "as one steady cycle they need J_T >= 0.065 M_min (in brackets: over the run's J_T); "
            'at the measured mean the drags would take (0.135 / mean)^2 and the ram 0.135 / mean '
            "times the run's. finer: the relative difference at twice the elements and half the "
            'step.',
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
