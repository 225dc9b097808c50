"""
Paper 000 study, experiment K: the exact momentum of the water inside against `rho S V'`.

docs/theory/shell.md, "Experiment K" (corrections): for any incompressible flow in the cavity the
water's axial momentum relative to the body is exactly `rho dM1/dt`, `M1 = int z dV` the cavity's
first moment about its opening plane (the water leaving crosses `z = 0`); K's `rho S V'` (`S` the
reference cavity's centroid height, `M1 / V` at rest) equals it for a uniform dilation only. This
reruns experiment K's internal cases of the paper coupling, measures `M1` of the mesh at every
step, and reports `dM1/dt` over `S dV/dt` while the jet flows (|V'| above 30 % of its largest),
at the study's resolution and at twice the elements and half the step. A diagnostic: the runs'
dynamics are K's. Second table: where the 80 kPa ellipsoid's peaks fall under I and K, and what
the water's momentum `rho S |V'| / m` is worth there (peaks over every step; the study's tables
take them from the published samples, so theirs can read a little lower). Writes
benchmarks/results/paper000_study/first_moment.md.

    .venv/bin/python -m benchmarks.validation.paper000_first_moment
"""

from __future__ import annotations

import math
import time

from benchmarks import common
from benchmarks.validation import paper000_experiments as experiments
from benchmarks.validation import paper000_study as study
import numpy as np
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.sweep import load_sweep, merge

OUT = study.OUT / 'first_moment.md'
FLOWING = 0.3  # of the run's largest |V'|: the steps where the momentum matters


def first_moment_and_volume(q: np.ndarray, n_nodes: int) -> tuple[float, float]:
    """Return (M1 m^4, V m^3) of the cavity between the meridian and the axis, z from the edge."""
    r = q[0::3][:n_nodes]
    z = q[1::3][:n_nodes] - q[3 * (n_nodes - 1) + 1]
    ra, rb, za, zb = r[:-1], r[1:], z[:-1], z[1:]
    dz = za - zb
    s = ra * ra + ra * rb + rb * rb
    # int z pi r(z)^2 dz over each frustum, r linear in z
    w = 3.0 * ra * ra + 2.0 * ra * rb + rb * rb
    m1 = float(np.sum(math.pi * dz * (zb * s / 3.0 + dz * w / 12.0)))
    return m1, float(np.sum(math.pi / 3.0 * s * dz))


def momentum_ratio(spec, refined: bool) -> dict:
    """Return dM1/dt over S dV/dt of one run while its jet flows, and M1 / V at rest over S."""
    overrides = merge(dict(spec.overrides), study.REFINED) if refined else dict(spec.overrides)
    model = load_scene(spec.scene, overrides, replace=spec.replace).model
    state = model.initial_state()
    n1, dt = model.n_nodes, model.dt_s
    s_m = float(model.P[sk.P_SMOM])
    rest_m1, rest_v = first_moment_and_volume(state, n1)
    moments = []
    for k in range(int(round(spec.duration_s / dt))):
        model.advance(state, k * dt, 1, Command())
        moments.append(first_moment_and_volume(state, n1))
    m1, vol = np.array(moments).T
    ratio = np.gradient(m1, dt) / (s_m * np.gradient(vol, dt))
    flowing = np.abs(np.gradient(vol, dt)) > FLOWING * np.abs(np.gradient(vol, dt)).max()
    r = ratio[flowing]
    return {
        'rest': rest_m1 / rest_v / s_m,
        'median': float(np.median(r)),
        'p05': float(np.percentile(r, 5)),
        'p95': float(np.percentile(r, 95)),
    }


def peak_and_momentum(spec) -> dict:
    """Return the peak speed of a run, its time and phase in the period, and rho S |V'|/m then."""
    model = load_scene(spec.scene, dict(spec.overrides), replace=spec.replace).model
    state = model.initial_state()
    n1, dt = model.n_nodes, model.dt_s
    speeds, rates, volumes = [], [], []
    for k in range(int(round(spec.duration_s / dt))):
        model.advance(state, k * dt, 1, Command())
        stats = model._eval(state)[0]
        speeds.append(state[6 * n1 + sk.S_U])
        rates.append(stats[sk.T_VDOT])
        volumes.append(stats[sk.T_VOL])
    i = int(np.argmax(speeds))
    rho = float(model.P[sk.P_RHO])
    mass = float(model.P[sk.P_MBODY] + model.P[sk.P_MSHELL]) + rho * volumes[i]
    s_m = float(model.ref.internal_momentum_length_m())
    period = 1.0 / float(model.P[sk.P_FREQ])
    return {
        'peak': float(speeds[i]),
        'time': (i + 1) * dt,
        'phase': ((i + 1) * dt % period) / period,
        'rate': float(rates[i]),
        'worth': rho * s_m * abs(rates[i]) / mass,
    }


def main() -> None:
    _, runs = load_sweep(study.SWEEP)
    change = experiments.EXPERIMENTS['internal_momentum'].change
    cases = [r for r in runs if r.study == 'internal' and dict(r.labels)['coupling'] == 'paper']
    started = time.time()
    lines = [
        '| run | rest M1/V over S | dM1/dt over S dV/dt: median (5-95 %) | refined: median '
        '(5-95 %) |',
        '|---|---|---|---|',
    ]
    for spec in cases:
        base = momentum_ratio(change(spec), False)
        fine = momentum_ratio(change(spec), True)
        row = (
            f"| {spec.name} | {base['rest']:.5f} | {base['median']:.3f} "
            f"({base['p05']:.3f}-{base['p95']:.3f}) | {fine['median']:.3f} "
            f"({fine['p05']:.3f}-{fine['p95']:.3f}) |"
        )
        print(row, flush=True)
        lines.append(row)
    lines += [
        '',
        '| run | reading | peak (m/s) | at (s) | phase in the period | dV/dt then (m^3/s) | '
        'rho S abs(dV/dt) / m then (m/s) |',
        '|---|---|---|---|---|---|---|',
    ]
    for name in ('internal/paper/ellipsoid/E80k/T0.53', 'internal/paper/ellipsoid/E80k/T0.66'):
        spec = next(r for r in cases if r.name == name)
        for key in ('internal_inertia', 'internal_momentum'):
            p = peak_and_momentum(experiments.EXPERIMENTS[key].change(spec))
            row = (
                f"| {name} | {experiments.EXPERIMENTS[key].letter} | {p['peak']:.4f} | "
                f"{p['time']:.3f} | {p['phase']:.2f} | {p['rate']:.3g} | {p['worth']:.4f} |"
            )
            print(row, flush=True)
            lines.append(row)
    wall = time.time() - started
    header = common.header(
        'Experiment K: the exact momentum of the water inside over the one-dimensional one',
        'python -m benchmarks.validation.paper000_first_moment',
    )
    header += (
        f'One process, {wall:.0f} s wall.\n\n'
        + (__doc__ or '').split('\n\n')[1].replace('\n', ' ')
        + '\n\n'
    )
    OUT.write_text(header + '\n'.join(lines) + '\n')
    print(f'wrote {OUT}')


if __name__ == '__main__':
    main()
