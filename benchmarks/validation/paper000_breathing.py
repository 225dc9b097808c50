"""
Paper 000 study, experiment F.1: the mantles' free breathing.

docs/theory/shell.md, "Experiment F".

Not the study: the study's internal scenes with the muscle off, started inflated by 3 mm
(`initial.radial_perturbation_m`, r += d sin(pi X/L)), at the study's wall viscosity and with it
off; every run again at twice the elements and half the step. Measures, from the volume's
departure from rest, whether the mantle swings through rest, its overshoot, damping ratio and
period. Writes benchmarks/results/paper000_study/breathing.md.

    .venv/bin/python -m benchmarks.validation.paper000_breathing
"""

from __future__ import annotations

import datetime
import math
import os
import platform
import re
import sys
import time


from benchmarks.validation import paper000_study as study
from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.sweep import load_sweep, merge

OUT = study.OUT / 'breathing.md'
PERTURBATION_M = 3e-3  # 10 % of the mantles' 30 mm largest radius
DURATION_S = 1.5
# the study's; a tenth of it (experiment F.2's); off (mesh-scale crumpling then goes undamped, so
# runs may stop: their first swings still give the period)
VISCOSITIES_PA_S = (500.0, 50.0, 0.0)
REST_TOLERANCE = 1e-4  # of x0: closer to rest than this is rest (round-off, not a swing)


def free_response(spec, viscosity_pa_s: float, refined: bool) -> dict:
    """Return the volume's free response of `spec`'s mantle inflated and let go."""
    overrides = merge(
        dict(spec.overrides),
        {
            'actuation': {'kind': 'none'},
            'material': {'viscosity_pa_s': viscosity_pa_s},
            'initial': {'radial_perturbation_m': PERTURBATION_M},
        },
    )
    if refined:
        overrides = merge(overrides, study.REFINED)
    rest_overrides = merge(overrides, {'initial': {'radial_perturbation_m': 0.0}})
    rest_volume = Simulation(
        load_scene(spec.scene, rest_overrides, replace=spec.replace).model
    ).observe().volume_m3
    scene = load_scene(spec.scene, overrides, replace=spec.replace)
    sim = Simulation(scene.model)
    times, excess = [0.0], [sim.observe().volume_m3 - rest_volume]
    fault = ''
    steps = int(round(DURATION_S / scene.model.dt_s))
    try:
        for _ in range(steps):
            obs = sim.step(1, sim.command)
            times.append(obs.time_s)
            excess.append(obs.volume_m3 - rest_volume)
    except SimulationBlowUp as err:
        fault = str(err).split('\n')[0]
    return {'x0': excess[0], **measure(times, excess), 'fault': fault}


def crossings(times: list[float], x: list[float], tol: float) -> list[float]:
    """
    Return the times where x changes sign (linear interpolation).

    Values within `tol` of zero are rest, not a side: round-off around rest is no swing.
    """
    out = []
    side, last = 0, None
    for i, v in enumerate(x):
        if abs(v) <= tol:
            continue
        s = 1 if v > 0 else -1
        if side and s != side:
            t0, v0 = times[last], x[last]
            out.append(t0 + (times[i] - t0) * v0 / (v0 - v))
        side, last = s, i
    return out


def measure(times: list[float], x: list[float]) -> dict:
    x0 = x[0]
    cross = crossings(times, x, REST_TOLERANCE * x0)
    first_e = next((t for t, v in zip(times, x) if v < x0 / math.e), math.nan)
    if not cross:
        return {'overshoot': 0.0, 'zeta': math.nan, 'period_s': math.nan, 't_1_e_s': first_e}
    after = [v for t, v in zip(times, x) if t > cross[0]]
    swing = -min(after) / x0
    zeta = -math.log(swing) / math.hypot(math.pi, math.log(swing)) if swing > 0 else math.nan
    period = 2.0 * (cross[1] - cross[0]) if len(cross) > 1 else math.nan
    return {'overshoot': swing, 'zeta': zeta, 'period_s': period, 't_1_e_s': first_e}


def stopped(fault: str) -> str:
    """Return when a run stopped, or a dash, from its SimulationBlowUp message."""
    if not fault:
        return '-'
    found = re.search(r'stopped at t=([0-9.]+) s', fault)
    return f'stopped at {found.group(1)} s' if found else fault


def fmt(v: float, spec: str) -> str:
    return '-' if not math.isfinite(v) else format(v, spec)


def main() -> int:
    _, runs = load_sweep(study.SWEEP)
    cases = [r for r in runs if r.study == 'internal' and dict(r.labels)['routine'] == 'T0.66']
    start = time.perf_counter()
    lines = []
    worst = 0.0
    for spec in cases:
        labels = dict(spec.labels)
        for viscosity in VISCOSITIES_PA_S:
            res = free_response(spec, viscosity, refined=False)
            fine = free_response(spec, viscosity, refined=True)
            for key in ('overshoot', 'period_s'):
                if res['fault'] or fine['fault'] or not res[key] > 0:
                    continue  # a stopped run is reported as such, not as a resolution error
                error = abs(res[key] / fine[key] - 1.0) if fine[key] > 0 else math.inf
                worst = max(worst, error)
            name = f'{labels["coupling"]}/{labels["mantle"]}/{labels["stiffness"]}'
            print(name, viscosity, res, fine, file=sys.stderr, flush=True)
            period = res['period_s']
            lines.append(
                f'| {name} | {viscosity:g} | {res["x0"] * 1e6:.2f} | '
                f'{"yes" if res["overshoot"] > 0 else "no"} | {fmt(res["overshoot"], ".3f")} '
                f'({fmt(fine["overshoot"], ".3f")}) | {fmt(res["zeta"], ".2f")} | '
                f'{fmt(period, ".4f")} ({fmt(fine["period_s"], ".4f")}) | '
                f'{fmt(1.0 / period if period > 0 else math.nan, ".2f")} | '
                f'{fmt(res["t_1_e_s"], ".4f")} | '
                f'{stopped(res["fault"])} ({stopped(fine["fault"])}) |'
            )
    wall = time.perf_counter() - start
    now = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    text = (
        '# Paper 000 study, experiment F.1: free breathing of the mantles\n\n'
        f'{now}, {platform.machine()}, {os.cpu_count()} cores, '
        f'Python {platform.python_version()}; '
        f'command `.venv/bin/python -m benchmarks.validation.paper000_breathing`, one process, '
        f'{wall:.0f} s wall.\n\n'
        'Not the study (docs/theory/shell.md, "Experiment F", written before this ran): the '
        "study's internal scenes (96 elements, 0.5 ms; the routine's label does not matter "
        f'with the muscle off) with no actuation, started inflated by {PERTURBATION_M * 1e3:g} '
        f'mm (r += d sin(pi X/L)), {DURATION_S:g} s, at the study' + "'" + 's wall viscosity '
        '(500 Pa s), a tenth of it and with it off. x0: the volume above rest at t = 0. Swings: '
        'whether the volume passes through rest. Overshoot: the largest excursion beyond rest '
        'after the first crossing, over x0; zeta = -ln OS / sqrt(pi^2 + ln^2 OS). Period: twice '
        'the time between the first two crossings of rest. 1/e: the time to fall to x0/e. In '
        'brackets: the same run at 192 elements, 0.25 ms. Routines of the study: 1.27-1.89 '
        'Hz.\n\n'
        '| mantle | eta_v (Pa s) | x0 (ml) | swings | overshoot (refined) | zeta | period s '
        '(refined) | f (Hz) | 1/e (s) | stopped (refined) |\n'
        '|---|---:|---:|---|---|---:|---|---:|---:|---|\n' + '\n'.join(lines) + '\n\n'
        'Resolution: largest relative change of overshoot or period at 192 elements / 0.25 ms, '
        f'over the runs that did not stop: {worst * 100:.2f} %.\n'
    )
    OUT.write_text(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
