"""
Resolution of paper 000's study before it runs.

Resolution of paper 000's study (config/sweeps/paper000_study.yaml) before it runs: four corner
cases of the study (softest and stiffest mantle, fastest routine, both actuations and mantles) in
both couplings at three meshes/steps (elements x2 and step /2 from one to the next), peak speed
against the finest.
Numerics only: it looks at no finding. Writes benchmarks/results/paper000_study/resolution.md.

    .venv/bin/python -m benchmarks.validation.paper000_resolution
"""

from __future__ import annotations

import datetime
import math
import platform
import sys
import time


from benchmarks.common import RESULTS
from pulsejet_sim.studies.sweep import load_sweep, merge, run_one, RunSpec

OUT = RESULTS / 'paper000_study'
CORNERS = (
    (
        'external',
        {'mantle': 'cone', 'stiffness': 'E20k', 'routine': 'T0.53', 'distribution': 'rising'},
    ),
    (
        'external',
        {
            'mantle': 'ellipsoid',
            'stiffness': 'E80k',
            'routine': 'T0.53',
            'distribution': 'falling',
        },
    ),
    ('internal', {'mantle': 'cone', 'stiffness': 'E80k', 'routine': 'T0.53'}),
    ('internal', {'mantle': 'ellipsoid', 'stiffness': 'E20k', 'routine': 'T0.53'}),
)
CASES = tuple(
    (study, {'coupling': c, **labels})
    for c in ('paper', 'consistent')
    for study, labels in CORNERS
)
LEVELS = ((48, 1e-3), (96, 5e-4), (192, 2.5e-4))


def at_resolution(spec: RunSpec, elements: int, dt_s: float) -> RunSpec:
    overrides = merge(
        dict(spec.overrides), {'mesh': {'elements': elements}, 'simulation': {'dt_s': dt_s}}
    )
    return RunSpec(spec.study, spec.labels, spec.scene, overrides, spec.duration_s, spec.replace)


def observed_order(values: list[float]) -> str:
    """Return log2(|f1 - f2| / |f2 - f3|) of three levels refined by 2, as text."""
    coarse, middle = abs(values[0] - values[1]), abs(values[1] - values[2])
    if not all(math.isfinite(v) for v in values) or coarse == 0.0 or middle == 0.0:
        return 'n/a'
    return f'{math.log2(coarse / middle):.2f}'


def main() -> int:
    _, runs = load_sweep('paper000_study')
    lines = [
        (
            '# Resolution of the paper 000 study'
            f' ({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC},'
            f' {platform.machine()}, Python {platform.python_version()},'
            ' `python -m benchmarks.validation.paper000_resolution`)'
        ),
        '',
        (
            'Peak vehicle speed (m/s) of four corner cases of `config/sweeps/paper000_study.yaml`;'
            ' error against the finest level; observed order p = log2(|f1 - f2| / |f2 - f3|) of'
            ' the three levels (elements doubled and step halved together; the scheme and the'
            ' work-equivalent loads are second order, so p near 2 says the levels are in the'
            ' asymptotic range, a p far from it that they are not).'
        ),
        '',
        '| case | '
        + ' | '.join(f'{n} el, {dt * 1e3:g} ms' for n, dt in LEVELS)
        + ' | errors | observed order | wall s |',
        '|---|' + '---|' * (len(LEVELS) + 3),
    ]
    for study, labels in CASES:
        spec = next(r for r in runs if r.study == study and dict(r.labels) == labels)
        start = time.perf_counter()
        peaks = []
        for n, dt in LEVELS:
            row = run_one(at_resolution(spec, n, dt))
            peaks.append(
                row.metrics['peak_speed_m_s'] if row.metrics and not row.fault else float('nan')
            )
        wall = time.perf_counter() - start
        errors = ', '.join(f'{abs(p / peaks[-1] - 1) * 100:.2f} %' for p in peaks[:-1])
        lines.append(
            f'| {spec.name} | '
            + ' | '.join(f'{p:.4f}' for p in peaks)
            + f' | {errors} | {observed_order(peaks)} | {wall:.0f} |'
        )
        print(lines[-1], flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / 'resolution.md').write_text('\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
