"""
Paper 000 study, experiment F.3: the internal ellipsoid's response to the routine's frequency.

docs/theory/shell.md, "Experiment F". Not the study: the study's internal ellipsoid at 20 kPa in
the `paper` coupling, its routine's frequency swept (contraction 30 % and release 45 % of the
period, half cosines, as the study's first version's routines), at the study's wall viscosity and
a tenth of it; every run again at twice the elements and half the step. Writes
benchmarks/results/paper000_study/frequency.md.

    .venv/bin/python -m benchmarks.validation.paper000_frequency
"""

from __future__ import annotations

import datetime
import math
import os
import platform
import sys
import time


from benchmarks.validation import paper000_study as study
from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.sweep import load_sweep, merge

OUT = study.OUT / 'frequency.md'
CASE = 'internal/paper/ellipsoid/E20k/T0.66'
FREQUENCIES_HZ = (1.27, 1.89, 2.5, 3.5, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 12.0)
# fractions of the period, half cosines: the routines of the study's first version, on which
# experiments A-F ran
CONTRACTION, RELEASE = 0.30, 0.45
VISCOSITIES_PA_S = (500.0, 50.0)
DURATION_S = 4.0


def response(spec, frequency_hz: float, viscosity_pa_s: float, resolution: dict) -> dict:
    """Return the last full period's volume stroke and the run's peak speed."""
    period = 1.0 / frequency_hz
    overrides = merge(
        dict(spec.overrides),
        {
            'material': {'viscosity_pa_s': viscosity_pa_s},
            'actuation': {
                'frequency_hz': frequency_hz,
                'contraction_s': CONTRACTION * period,
                'release_s': RELEASE * period,
                'pulse': 'half_cosine',
            },
        },
    )
    overrides = merge(overrides, resolution)
    sim = Simulation(load_scene(spec.scene, overrides, replace=spec.replace).model)
    last_start = (math.floor(DURATION_S / period) - 1) * period
    volumes, peak, edge, fault = [], 0.0, math.inf, ''
    try:
        for _ in range(int(round(DURATION_S / sim.model.dt_s))):
            obs = sim.step(1, sim.command)
            peak = max(peak, abs(obs.velocity_m_s))
            edge = min(edge, float(sim.profile()[0][-1]))  # the free edge: the nozzle
            if last_start <= obs.time_s < last_start + period:
                volumes.append(obs.volume_m3)
    except SimulationBlowUp as err:
        fault = str(err).split(' (')[0]
    stroke = max(volumes) - min(volumes) if volumes and not fault else math.nan
    return {'stroke_m3': stroke, 'peak_m_s': peak, 'edge_min_m': edge, 'fault': fault}


def change(run: dict, reference: dict) -> float:
    """Return the larger relative change of stroke and peak speed from `reference` to `run`."""
    return max(
        abs(run['stroke_m3'] / reference['stroke_m3'] - 1.0),
        abs(run['peak_m_s'] / reference['peak_m_s'] - 1.0),
    )


def main() -> int:
    _, runs = load_sweep(study.SWEEP)
    spec = next(r for r in runs if r.name == CASE)
    start = time.perf_counter()
    table, finer = {}, {}
    worst = 0.0
    for viscosity in VISCOSITIES_PA_S:
        for f in FREQUENCIES_HZ:
            res = response(spec, f, viscosity, {})
            fine = response(spec, f, viscosity, study.REFINED)
            table[viscosity, f] = res, fine
            if not (res['fault'] or fine['fault']):
                error = change(res, fine)
                worst = max(worst, error)
                if error > study.CONVERGED:
                    finer[viscosity, f] = response(spec, f, viscosity, study.FINER), error
            print(viscosity, f, res, fine, file=sys.stderr, flush=True)
    lines = []
    for viscosity in VISCOSITIES_PA_S:
        base = table[viscosity, FREQUENCIES_HZ[0]][0]['stroke_m3']
        for f in FREQUENCIES_HZ:
            res, fine = table[viscosity, f]
            lines.append(
                f'| {viscosity:g} | {f:g} | {res["stroke_m3"] * 1e6:.2f} '
                f'({fine["stroke_m3"] * 1e6:.2f}) | {res["stroke_m3"] / base:.3f} | '
                f'{res["peak_m_s"]:.4g} ({fine["peak_m_s"]:.4g}) | '
                f'{res["edge_min_m"] * 1e3:.2f} ({fine["edge_min_m"] * 1e3:.2f}) | '
                f'{res["fault"] or fine["fault"] or "-"} |'
            )
    finer_lines = []
    for (viscosity, f), (res, error) in finer.items():
        fine = table[viscosity, f][1]
        finer_lines.append(
            f'- {viscosity:g} Pa s, {f:g} Hz: {error * 100:.1f} % at 192 elements; at 384 '
            f'elements, 0.125 ms: stroke {res["stroke_m3"] * 1e6:.2f} ml, peak '
            f'{res["peak_m_s"]:.4g} m/s, edge min {res["edge_min_m"] * 1e3:.2f} mm, '
            f'{change(fine, res) * 100:.2f} % from the 192-element run'
            + (f' ({res["fault"]})' if res['fault'] else '')
        )
    wall = time.perf_counter() - start
    now = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    text = (
        '# Paper 000 study, experiment F.3: '
        "the ellipsoid's response to the routine's frequency\n\n"
        f'{now}, {platform.machine()}, {os.cpu_count()} cores, '
        f'Python {platform.python_version()}; '
        f'command `.venv/bin/python -m benchmarks.validation.paper000_frequency`, one process, '
        f'{wall:.0f} s wall.\n\n'
        'Not the study (docs/theory/shell.md, "Experiment F", written before this ran): '
        f'`{CASE}` (96 elements, 0.5 ms) with the routine at each frequency, contraction '
        f'{CONTRACTION:.0%} and release {RELEASE:.0%} of the period (half cosines, as in the '
        f"study's first version), {DURATION_S:g} s, at the "
        "study's wall viscosity and a tenth of it. Stroke: largest minus smallest volume over "
        'the last full period; relative: over the stroke at the slowest routine. Edge radius: '
        'the smallest radius of the free edge (the nozzle; 12.5 mm at rest) over the run. In '
        'brackets: '
        'the same run at 192 elements, 0.25 ms. The study routines: 1.27, 1.52, 1.89 Hz.\n\n'
        '| eta_v (Pa s) | routine (Hz) | stroke ml (refined) | relative | peak speed m/s '
        '(refined) | edge radius min mm (refined) | stopped |\n'
        '|---:|---:|---|---:|---|---|---|\n' + '\n'.join(lines) + '\n\n'
        'Resolution: largest relative change of stroke or peak speed at 192 elements / '
        f'0.25 ms, over the runs that did not stop: {worst * 100:.2f} %. Runs that moved by more '
        f'than {study.CONVERGED:.0%}, again at 384 elements, 0.125 ms:\n\n'
        + ('\n'.join(finer_lines) or '- none')
        + '\n'
    )
    OUT.write_text(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
