"""
Experiment G (an analysis of the stored study, no new run): what the routine does to each mantle.

Paper 000, section 5.2, Fig. 17: "The conical mantle performances are almost independent of the
actuation routine, while the ellipsoidal mantle, in test number 9, benefits from a particular
resonance". The study's routines differ only in their period (0.53, 0.66, 0.79 s, the authors'
code), so a mantle that follows its muscle quasi-statically expels the same stroke at every
routine, at a mean rate that scales as 1/period, and its peak speed follows that rate: a spread of
0.79/0.53 = 1.49 between the slowest and the fastest routine. "Almost independent" needs a stroke
that shrinks as the routine quickens (a dynamic limit of the wall); a resonance needs one that
grows. This script splits each internal case's routine spread into the stroke's spread and the
rate's, from `study.csv` (the columns `volume_max_m3 - volume_min_m3` and `peak_speed_m_s`), and
writes `benchmarks/results/paper000_study/routines.md`.

    .venv/bin/python benchmarks/paper000_routines.py
"""

from __future__ import annotations

from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_common import header  # noqa: E402
import paper000_study as study  # noqa: E402


def period_s(routine: str) -> float:
    """Return the period of a study routine label ('T0.53' -> 0.53)."""
    return float(routine[1:])


def stroke_m3(row: dict) -> float:
    return row['volume_max_m3'] - row['volume_min_m3']


def spreads(rows: list[dict]) -> list[dict]:
    """
    Split each (coupling, mantle, stiffness) internal case's routine spread into its factors.

    For the slowest-swimming and the fastest-swimming routine: peak-speed ratio, stroke ratio, and
    period ratio (slow period / fast period, what a quasi-static stroke gives). The peak-speed
    ratio is the stroke ratio times the period ratio times what is left (`rest`).
    """
    out = []
    internal = [r for r in rows if r['study'] == 'internal']
    cases = sorted({(r['coupling'], r['mantle'], r['stiffness']) for r in internal})
    for coupling, mantle, stiffness in cases:
        runs = study.select(internal, coupling=coupling, mantle=mantle, stiffness=stiffness)
        fast = max(runs, key=study.speed)
        slow = min(runs, key=study.speed)
        strokes = [stroke_m3(r) for r in runs]
        speed_ratio = study.speed(fast) / study.speed(slow)
        stroke_ratio = stroke_m3(fast) / stroke_m3(slow)
        period_ratio = period_s(slow['routine']) / period_s(fast['routine'])
        out.append(
            {
                'coupling': coupling,
                'mantle': mantle,
                'stiffness': stiffness,
                'fast': fast['routine'],
                'slow': slow['routine'],
                'speed_ratio': speed_ratio,
                'stroke_ratio': stroke_ratio,
                'period_ratio': period_ratio,
                'rest': speed_ratio / (stroke_ratio * period_ratio),
                'stroke_spread': max(strokes) / min(strokes),
                'strokes_ml': [s * 1e6 for s in strokes],
            }
        )
    return out


def main() -> int:
    rows = study.read_table(study.OUT / 'study.csv')
    lines = [
        '| coupling | mantle | E | fastest / slowest routine | peak speed ratio | stroke ratio |'
        ' period ratio (slow / fast) | rest | strokes (ml, T0.53 / 0.66 / 0.79) |',
        '|---|---|---|---|---:|---:|---:|---:|---|',
    ]
    for s in spreads(rows):
        lines.append(
            f'| {s["coupling"]} | {s["mantle"]} | {s["stiffness"]} | {s["fast"]} / {s["slow"]} |'
            f' {s["speed_ratio"]:.3f} | {s["stroke_ratio"]:.3f} | {s["period_ratio"]:.3f} |'
            f' {s["rest"]:.3f} | ' + ' / '.join(f'{v:.1f}' for v in s['strokes_ml']) + ' |'
        )
    text = (
        header(
            "Experiment G: the routine's effect split into stroke and rate",
            'python benchmarks/paper000_routines.py',
        )
        + 'An analysis of the stored `study.csv` (second version; no new run). Peak speed ratio ='
        ' stroke ratio x period ratio x rest, between the fastest- and the slowest-swimming'
        ' routine of each internal case. A mantle that follows its muscle quasi-statically has'
        ' stroke ratio 1 and rest 1, so its peak speed ratio is the period ratio (1.49 between'
        ' 0.53 and 0.79 s). The paper\'s "almost independent" (our rule: peak speed ratio <= 1.15)'
        ' needs stroke ratio x rest <= 1.15 / 1.49 = 0.77.\n\n' + '\n'.join(lines) + '\n'
    )
    path = study.OUT / 'routines.md'
    path.write_text(text)
    print(text)
    print(f'written to {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
