"""
Experiment G: what the routine does to each internal mantle of paper 000's study.

Paper 000, section 5.2, Fig. 17: "The conical mantle performances are almost independent of the
actuation routine, while the ellipsoidal mantle, in test number 9, benefits from a particular
resonance". The study's routines differ only in their period (0.53, 0.66, 0.79 s, the authors'
code), so a mantle that follows its muscle expels the same stroke at every routine at a rate that
scales as 1/period (a spread of 0.79/0.53 = 1.49); "almost independent" needs a stroke that
shrinks as the routine quickens, by about that ratio. `--rerun` reruns every internal case as it
is (and again at 192 elements / 0.25 ms), reading the volume every step: the stroke over the whole
run (as the study's columns) and over the last full period, the peak speed and its time
(`routines.csv`). Without it the stored rows are read. The table splits each case's routine
spread into the last period's stroke ratio, the period ratio and a rest, beside a first-order lag
of the wall's relaxation time 3 eta / E (`lag_strokes`); written to
`benchmarks/results/paper000_study/routines.md`. docs/theory/shell.md, "Experiment G".

    .venv/bin/python -m benchmarks.validation.paper000_routines [--rerun]
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import sys


from benchmarks.common import header, write
from benchmarks.validation import paper000_study as study
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.sweep import load_sweep, merge

CYCLES_CSV = study.OUT / 'routines.csv'
LAGS_S = (0.019, 0.0375, 0.075, 0.12, 0.25, 0.5, 1.0)
CYCLE_COLUMNS = ('peak_speed_m_s', 'peak_time_s', 'run_stroke_m3', 'cycle_stroke_m3')


def period_s(routine: str) -> float:
    """Return the period of a study routine label ('T0.53' -> 0.53)."""
    return float(routine[1:])


def stroke_m3(row: dict) -> float:
    return row['volume_max_m3'] - row['volume_min_m3']


def spreads(rows: list[dict], cycles: list[dict]) -> list[dict]:
    """
    Split each (coupling, mantle, stiffness) internal case's routine spread into its factors.

    rows: the study's table; cycles: read_cycles(). Between the fastest- and the slowest-swimming
    routine: peak-speed ratio, stroke ratios (whole run, the study's columns; last period), period
    ratio (slow / fast: what an unchanged stroke gives) and the rest, peak speed ratio / (last
    period's stroke ratio x period ratio), an identity's residual. lag: the last period's stroke
    ratio of a first-order lag of 3 eta / E (lag_strokes).
    """
    out = []
    by_run = {c['run']: c for c in cycles}
    internal = [r for r in rows if r['study'] == 'internal']
    _, specs = load_sweep(study.SWEEP)
    material = {spec.name: spec.overrides['material'] for spec in specs}
    cases = sorted({(r['coupling'], r['mantle'], r['stiffness']) for r in internal})
    for coupling, mantle, stiffness in cases:
        runs = study.select(internal, coupling=coupling, mantle=mantle, stiffness=stiffness)
        fast = max(runs, key=study.speed)
        slow = min(runs, key=study.speed)
        cf, cs = by_run[fast['run']], by_run[slow['run']]
        speed_ratio = study.speed(fast) / study.speed(slow)
        cycle_ratio = cf['cycle_stroke_m3'] / cs['cycle_stroke_m3']
        period_ratio = period_s(slow['routine']) / period_s(fast['routine'])
        m = material[fast['run']]
        lag_s = 3.0 * m['viscosity_pa_s'] / m['youngs_modulus_pa']
        lag_fast = lag_strokes(period_s(fast['routine']), lag_s)[1]
        lag_slow = lag_strokes(period_s(slow['routine']), lag_s)[1]
        out.append(
            {
                'coupling': coupling,
                'mantle': mantle,
                'stiffness': stiffness,
                'fast': fast['routine'],
                'slow': slow['routine'],
                'speed_ratio': speed_ratio,
                'run_stroke_ratio': stroke_m3(fast) / stroke_m3(slow),
                'cycle_stroke_ratio': cycle_ratio,
                'period_ratio': period_ratio,
                'rest': speed_ratio / (cycle_ratio * period_ratio),
                'lag_s': lag_s,
                'lag_ratio': lag_fast / lag_slow,
                'peak_times_s': sorted(by_run[r['run']]['peak_time_s'] for r in runs),
                'cycle_strokes_ml': [
                    by_run[r['run']]['cycle_stroke_m3'] * 1e6
                    for r in sorted(runs, key=lambda r: period_s(r['routine']))
                ],
            }
        )
    return out


def cycle_strokes(spec, resolution: dict | None = None) -> dict:
    """
    Rerun one study case and return its strokes measured two ways, its peak speed and its time.

    run_stroke_m3: largest minus smallest volume over the run after the first step (as the study's
    columns: the largest is the rest volume at the start, so a wall that no longer returns to
    rest is not seen);
    cycle_stroke_m3: largest minus smallest volume over the last full period (what a lag shrinks).
    """
    overrides = merge(dict(spec.overrides), resolution or {})
    sim = Simulation(load_scene(spec.scene, overrides, replace=spec.replace).model)
    period = 1.0 / overrides['actuation']['frequency_hz']
    duration_s = spec.duration_s
    last_start = (math.floor(duration_s / period + 1e-9) - 1) * period
    volumes, cycle, peak, peak_time = [], [], 0.0, 0.0
    for _ in range(int(round(duration_s / sim.model.dt_s))):
        obs = sim.step(1, sim.command)
        if abs(obs.velocity_m_s) > peak:
            peak, peak_time = abs(obs.velocity_m_s), obs.time_s
        volumes.append(obs.volume_m3)
        if last_start <= obs.time_s < last_start + period:
            cycle.append(obs.volume_m3)
    return {
        'peak_speed_m_s': peak,
        'peak_time_s': peak_time,
        'run_stroke_m3': max(volumes) - min(volumes),
        'cycle_stroke_m3': max(cycle) - min(cycle),
    }


@functools.lru_cache(maxsize=None)  # the cases share three lags and three periods
def lag_strokes(period_s: float, lag_s: float, cycles: int = 14, steps: int = 4000):
    """
    Return (whole-run, last-period) strokes of a first-order lag x' = (u - x) / lag_s from x = 0.

    u: the study's triangle (0 -> 1 over half the period, back over the other half); explicit
    Euler, `steps` a period, `cycles` periods. The rough model of a wall that relaxes towards the
    muscle's desired shape in lag_s (experiment G).
    """
    dt = period_s / steps
    x, lo, hi, cycle_lo, cycle_hi = 0.0, 0.0, 0.0, math.inf, -math.inf
    for i in range(cycles * steps):
        phase = (i % steps) / steps
        u = 2.0 * phase if phase < 0.5 else 2.0 - 2.0 * phase
        x += dt * (u - x) / lag_s
        lo, hi = min(lo, x), max(hi, x)
        if i >= (cycles - 1) * steps:
            cycle_lo, cycle_hi = min(cycle_lo, x), max(cycle_hi, x)
    return hi - lo, cycle_hi - cycle_lo


def run_cycles() -> list[dict]:
    """Rerun every internal case at the study's resolution and refined; return the rows."""
    _, runs = load_sweep(study.SWEEP)
    out = []
    for spec in runs:
        if not spec.name.startswith('internal/'):
            continue
        base = cycle_strokes(spec)
        fine = cycle_strokes(spec, study.REFINED)
        row = {'run': spec.name, **base}
        row.update({f'refined_{k}': v for k, v in fine.items()})
        out.append(row)
        print(spec.name, row, flush=True)
    return out


def write_cycles(rows: list[dict]) -> None:
    columns = ['run', *CYCLE_COLUMNS, *(f'refined_{c}' for c in CYCLE_COLUMNS)]
    with open(CYCLES_CSV, 'w', newline='') as fh:
        writer = csv.writer(fh, lineterminator='\n')
        writer.writerow(columns)
        for r in rows:
            writer.writerow([r['run']] + [repr(r[c]) for c in columns[1:]])


def read_cycles() -> list[dict]:
    with open(CYCLES_CSV) as fh:
        return [
            {k: (v if k == 'run' else float(v)) for k, v in r.items()} for r in csv.DictReader(fh)
        ]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        '--rerun',
        action='store_true',
        help='rerun the 36 internal cases (and refined) for the per-period strokes (~20 min)',
    )
    args = ap.parse_args()
    if args.rerun:
        write_cycles(run_cycles())
    rows = study.read_table(study.OUT / 'study.csv')
    cycles = read_cycles()
    stored = {r['run']: r for r in rows}
    peak_change = max(
        abs(c['peak_speed_m_s'] / stored[c['run']]['peak_speed_m_s'] - 1.0) for c in cycles
    )
    refined_change = max(
        max(
            abs(c[f'refined_{k}'] / c[k] - 1.0)
            for k in ('peak_speed_m_s', 'run_stroke_m3', 'cycle_stroke_m3')
        )
        for c in cycles
    )
    lines = [
        '| coupling | mantle | E | fastest / slowest routine | peak speed ratio | peak at (s) |'
        ' stroke ratio, whole run | stroke ratio, last period | lag estimate (3 eta / E) |'
        ' rest | last-period strokes (ml, T0.53 / 0.66 / 0.79) |',
        '|---|---|---|---|---:|---|---:|---:|---|---:|---|',
    ]
    for s in spreads(rows, cycles):
        lines.append(
            f'| {s["coupling"]} | {s["mantle"]} | {s["stiffness"]} | {s["fast"]} / {s["slow"]} |'
            f' {s["speed_ratio"]:.3f} | {s["peak_times_s"][0]:.2f}-{s["peak_times_s"][-1]:.2f} |'
            f' {s["run_stroke_ratio"]:.3f} | {s["cycle_stroke_ratio"]:.3f} |'
            f' {s["lag_ratio"]:.3f} ({s["lag_s"]:.3f} s) | {s["rest"]:.3f} | '
            + ' / '.join(f'{v:.1f}' for v in s['cycle_strokes_ml'])
            + ' |'
        )
    lag = [(t, lag_strokes(0.53, t), lag_strokes(0.79, t)) for t in LAGS_S]
    lag_lines = [
        '| lag (s) | whole run | last period |',
        '|---:|---:|---:|',
        *(f'| {t:g} | {a[0] / b[0]:.3f} | {a[1] / b[1]:.3f} |' for t, a, b in lag),
    ]
    text = (
        header(
            "Experiment G: the routine's effect split into stroke and rate",
            'python -m benchmarks.validation.paper000_routines [--rerun]',
        )
        + 'Every internal case of the study (second version) rerun as it is, its volume and speed'
        ' read every step (`routines.csv`; `--rerun` remakes it, ~10 min); the peak speeds equal'
        f" the stored study's within {peak_change:.1e} relative. Each case again at 192 elements"
        ' / 0.25 ms: peak speed and both strokes within'
        f' {refined_change:.2%}. Between the fastest- and the slowest-swimming routine of each'
        ' case, peak speed ratio = last-period stroke ratio x period ratio (0.79 / 0.53 = 1.491) x'
        " rest (the residual). Whole-run stroke: the study's `volume_max - volume_min` (the rest"
        ' volume at the start minus the deepest contraction); last period: the largest minus the'
        ' smallest volume over the last full period. Lag estimate: the last-period stroke ratio'
        " of a first-order lag of 3 eta / E driven by the study's triangle (`lag_strokes`). The"
        ' paper\'s "almost independent" (our rule: peak speed ratio <= 1.15) needs last-period'
        ' stroke ratio x rest <= 1.15 / 1.491 = 0.771.\n\n'
        + '\n'.join(lines)
        + '\n\nThe lag alone (stroke ratio T 0.53 s / T 0.79 s, both measures):\n\n'
        + '\n'.join(lag_lines)
        + '\n'
    )
    write('paper000_study/routines', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
