"""
Benchmark (not a test): speed-accuracy trade of the lumped model's integrators.

Scenes escape (3 s) and pump_cycle (10 s, the routine's command sequence recorded once at 100 Hz
from a fixed-step run and replayed open loop, so every integrator sees the same inputs). Outputs at
the publication rate (100 Hz): the fixed-step RK4 in batches of one publication
(``LumpedModel._advance_rk4``, what Simulation.step runs), the adaptive Dormand-Prince 5(4) in one
call per constant-command segment with dense output at the publication times
(``LumpedModel.advance_dense``). Reference: adaptive at rtol 1e-12, atol 1e-15 (RK4 at dt = 1e-5 s
is a row of the table, to cross-check it). Errors: peak speed over the 100 Hz outputs and the
distance at the end, relative to the reference; energy-ledger closure at the end. Wall time: the
best of 5 repetitions (compilation excluded), one core. Writes
benchmarks/results/lumped_adaptive.md.

    .venv/bin/python -m benchmarks.performance.bench_lumped_adaptive
"""

from __future__ import annotations

import functools
import sys
import time


from benchmarks.common import header, write
import numpy as np
from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.models.lumped import kernels as K
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import Drive

PUBLISH_S = 0.01
DURATION = {'escape': 3.0, 'pump_cycle': 10.0}


def schedule(scene_name: str):
    """
    List the constant commands of the scene's routine at 100 Hz.

    As [(start_s, end_s, command)].
    """
    scene = load_scene(scene_name)
    cmds = [(start, cmd) for start, cmd, _ in Drive(scene, DURATION[scene_name])]
    segs = []
    for start, cmd in cmds:
        if segs and segs[-1][2] == cmd:
            segs[-1][1] = start + PUBLISH_S
        else:
            segs.append([start, start + PUBLISH_S, cmd])
    return [tuple(s) for s in segs]


@functools.lru_cache(maxsize=None)
def build(scene_name, integrator, dt, rtol, atol):
    """Build the model, compiled once (scene loading is not part of the timing)."""
    sim = {'dt_s': dt, 'integrator': integrator, 'rtol': rtol, 'atol': atol}
    return load_scene(scene_name, {'simulation': sim}).model


def run_rk4(scene_name, segs, dt):
    model = build(scene_name, 'rk4', dt, 1e-6, 1e-9)
    y = model.initial_state()
    per = int(round(PUBLISH_S / dt))
    n_pub = int(round(DURATION[scene_name] / PUBLISH_S))
    u = np.empty(n_pub)
    k = 0
    for start, end, cmd in segs:
        for _ in range(int(round((end - start) / PUBLISH_S))):
            model._advance_rk4(y, k * PUBLISH_S, per, cmd)
            u[k] = y[K.Y_U]
            k += 1
    return model, y, u, n_pub * per


def run_adaptive(scene_name, segs, rtol, atol):
    model = build(scene_name, 'adaptive', 1e-4, rtol, atol)
    y = model.initial_state()
    us = []
    steps = 0
    for start, end, cmd in segs:
        n = int(round((end - start) / PUBLISH_S))
        t_out = np.arange(1, n + 1) * PUBLISH_S
        t_out[-1] = end - start
        out, stats = model.advance_dense(y, start, end - start, cmd, t_out)
        us.append(out[:, K.Y_U])
        steps += stats[K.S_ACCEPTED] + stats[K.S_REJECTED]
    return model, y, np.concatenate(us), int(steps)


def timed(fn, *args, repeat=5):
    fn(*args)  # compile / load
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        result = fn(*args)
        best = min(best, time.perf_counter() - t)
    return best, result


def main() -> int:
    rows = []
    verdict = []
    for scene_name in ('escape', 'pump_cycle'):
        segs = schedule(scene_name)
        _, (m_ref, y_ref, u_ref, _) = timed(run_adaptive, scene_name, segs, 1e-12, 1e-15, repeat=1)
        peak_ref, dist_ref = u_ref.max(), y_ref[K.Y_X]
        cases = [('RK4', f'dt = {dt:g} s', run_rk4, (dt,)) for dt in (1e-5, 1e-4, 1e-3)]
        cases += [
            ('DP5(4) adaptive', f'rtol = {r:g}, atol = {r * 1e-3:g}', run_adaptive, (r, r * 1e-3))
            for r in (1e-3, 1e-4, 1e-5, 1e-6, 1e-8)
        ]
        for name, tol, fn, extra in cases:
            try:
                wall, (model, y, u, steps) = timed(
                    fn, scene_name, segs, *extra, repeat=1 if extra == (1e-5,) else 5
                )
            except SimulationBlowUp as err:
                rows.append(
                    f'| {scene_name} | {name} | {tol} | fault: {str(err)[:90]}... | | | | | |'
                )
                continue
            e_peak = abs(u.max() - peak_ref) / abs(peak_ref)
            e_dist = abs(y[K.Y_X] - dist_ref) / abs(dist_ref)
            closure = model.energy_ledger(y[: K.NY])['closure_error']
            rtf = DURATION[scene_name] / wall
            rows.append(
                f'| {scene_name} | {name} | {tol} | {steps:,} | {wall * 1e3:.3f} | {rtf:,.0f}x | '
                f'{e_peak:.1e} | {e_dist:.1e} | {closure:.1e} |'
            )
            if name.startswith('DP5') and e_peak <= 1e-3 and e_dist <= 1e-3 and rtf >= 1e4:
                verdict.append(
                    f'{scene_name}: {tol} meets the target ({rtf:,.0f}x real time, errors '
                    f'{e_peak:.1e} / {e_dist:.1e})'
                )
        rows.append(
            f'| {scene_name} | reference: DP5(4) | rtol = 1e-12, atol = 1e-15 | | | | peak'
            f' {peak_ref:.6f} m/s | distance {dist_ref:.6f} m | |'
        )
    text = header(
        'Lumped model: adaptive vs fixed-step integrator, speed and accuracy',
        'python -m benchmarks.performance.bench_lumped_adaptive',
    ) + (
        'Outputs at 100 Hz; escape 3 s with a constant command, pump_cycle 10 s with the'
        " routine's commands replayed open loop (segments of constant command; the adaptive"
        ' integrator restarts its step at each). Steps: physics steps (RK4) or attempted steps,'
        ' accepted + rejected (DP5). Wall: best of 5, one core. Errors relative to the reference'
        ' (last rows); closure: energy-ledger closure error at the end, J.\n\n| scene | integrator'
        ' | step / tolerance | steps | wall ms | real-time factor | peak speed error | distance'
        ' error | closure J |\n|---|---|---|---:|---:|---:|---:|---:|---:|\n'
        + '\n'.join(rows)
        + '\n\nTarget (issue 9): >= 1e4 x real time within 0.1 % of the reference peak speed and'
        ' distance.\n\n'
        + ('\n'.join(f'- {v}' for v in verdict) if verdict else '- not met in this run')
        + '\n'
    )
    write('lumped_adaptive', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
