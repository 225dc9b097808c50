"""Paper 000's study (36 external + 18 internal actuation runs) through `pulsejet sweep`, and which
of the paper's qualitative findings it reproduces. Not a test: writes
benchmarks/results/paper_study/{paper_study.csv, paper_study.png, README.md}.

The findings are checked by rules fixed here, before looking at the numbers; the sweep's values
are in config/sweeps/paper_study.yaml and are not tuned per finding.
"""
from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pulsejet_sim.sweep import load_sweep, plot_bars, run_sweep, write_csv  # noqa: E402

OUT = Path(__file__).resolve().parent / 'results' / 'paper_study'


def peak(rows, **labels):
    return [r for r in rows if all(r.labels.get(k) == v for k, v in labels.items())]


def findings(rows) -> list[tuple[str, bool, str]]:
    speed = lambda r: r.metrics['peak_speed_m_s']  # noqa: E731
    ext = [r for r in rows if r.study == 'external' and r.metrics]
    inn = [r for r in rows if r.study == 'internal' and r.metrics]
    out = []
    top3 = sorted(ext, key=speed, reverse=True)[:3]
    stiffest = max({r.labels['stiffness'] for r in ext}, key=lambda s: float(s[1:-1]))
    ok = all(r.labels['mantle'] == 'ellipsoid' and r.labels['stiffness'] == stiffest for r in top3)
    out.append(('external: the stiffest ellipsoid gives the three highest peaks', ok,
                'top three: ' + ', '.join(f'{r.name} {speed(r):.3f} m/s' for r in top3)))
    ratios = {}
    for mantle in ('cone', 'ellipsoid'):
        values = []
        for r in peak(ext, mantle=mantle, distribution='rising'):
            twin = peak(ext, mantle=mantle, distribution='falling', stiffness=r.labels['stiffness'], routine=r.labels['routine'])
            values.append(max(speed(r), speed(twin[0])) / min(speed(r), speed(twin[0])))
        ratios[mantle] = sum(values) / len(values)
    ok = ratios["ellipsoid"] - 1.0 > 2.0 * (ratios["cone"] - 1.0)   # "much more": twice the spread
    out.append(('external: the spatial distribution matters much more for the ellipsoid than for the cone', ok,
                f'mean faster/slower ratio between the two distributions: ellipsoid {ratios["ellipsoid"]:.2f}, '
                f'cone {ratios["cone"]:.2f}'))
    best = max(inn, key=speed)
    stiffest_i = max({r.labels['stiffness'] for r in inn}, key=lambda s: float(s[1:-1]))
    ok = best.labels['mantle'] == 'cone' and best.labels['stiffness'] == stiffest_i
    out.append(('internal: the stiffest cone is best', ok, f'best: {best.name} {speed(best):.3f} m/s'))
    resonance = []
    for stiffness in sorted({r.labels['stiffness'] for r in inn}):
        group = peak(inn, mantle='ellipsoid', stiffness=stiffness)
        values = sorted(speed(r) for r in group)
        resonance.append((stiffness, values[-1] / values[0]))
    ok = any(ratio >= 1.8 for _, ratio in resonance)
    out.append(('internal: one ellipsoid routine resonates and doubles its speed', ok,
                'fastest/slowest routine per ellipsoid stiffness: ' + ', '.join(f'{s} {x:.2f}' for s, x in resonance)))
    return out


def robot_speeds(duration_s: float = 10.0) -> tuple[float, float]:
    """Mean speed over the last half of the run (cruise) and the peak (burst) of the cable-driven
    robot of the paper's discussion (config/shell_robot.yaml), m/s."""
    from pulsejet_sim.runner import Drive
    from pulsejet_sim.scene import load_scene
    samples = [(obs.time_s, obs.velocity_m_s) for _, _, obs in Drive(load_scene('shell_robot'), duration_s)]
    cruise = [v for t, v in samples if t >= duration_s / 2]
    return sum(cruise) / len(cruise), max(v for _, v in samples)


def main() -> int:
    meta, runs = load_sweep('paper_study')
    start = time.perf_counter()
    rows = run_sweep(runs)
    wall = time.perf_counter() - start
    OUT.mkdir(parents=True, exist_ok=True)
    write_csv(rows, OUT / 'paper_study.csv')
    plot_bars(rows, meta['metric'], OUT / 'paper_study.png')
    faults = [r for r in rows if r.fault]
    lines = [f'# Paper 000 study: {len(runs)} runs of {meta["duration_s"]:g} s',
             '',
             f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}, {os.cpu_count()} cores, '
             f'Python {platform.python_version()}, `benchmarks/paper_study.py` ({wall:.0f} s wall). '
             f'Sweep: `config/sweeps/paper_study.yaml` (values stated there, chosen once). '
             f'Table: `paper_study.csv`; plot: `paper_study.png`. Faults: {len(faults)}.',
             '', '| finding of the paper | reproduced | what the sweep shows |', '|---|---|---|']
    for text, ok, detail in findings(rows):
        lines.append(f'| {text} | {"yes" if ok else "no"} | {detail} |')
    for r in faults:
        lines.append(f'\nFAULT {r.name}: {r.fault}')
    mean, burst = robot_speeds()
    lines += ['', '## The cable-driven robot (paper 000, discussion; `config/shell_robot.yaml`, 1.6 Hz)', '',
              '| | measured (paper) | simulated |', '|---|---|---|',
              f'| mean speed | 0.135 m/s | {mean:.3f} m/s (last 5 s of 10 s) |',
              f'| burst speed | 0.2 m/s | {burst:.3f} m/s (peak) |']
    report = '\n'.join(lines) + '\n'
    (OUT / 'README.md').write_text(report)
    print(report)
    return 0


if __name__ == '__main__':
    sys.exit(main())
