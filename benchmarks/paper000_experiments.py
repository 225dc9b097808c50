"""Experiments that explain the paper 000 study's misses (benchmarks/results/paper000_study/README.md).
Not the study: its values stay as chosen; each experiment changes one reading of the lost text and
reruns the study's finding rules on it. Writes benchmarks/results/paper000_study/experiments.md.

    .venv/bin/python benchmarks/paper000_experiments.py

A. The cable load read as a strain instead of a force: the pull scales with the Young's modulus,
   15 N x E / 40 kPa, so every mantle is pulled to about the same deformation (findings 1, 2).
B. The muscle's desired radius read as `proportional` (a uniform fraction of the rest radius)
   instead of `constant_depth` (findings 3, 4, 5).
"""
from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import paper000_study as study  # noqa: E402
from pulsejet_sim.sweep import RunSpec, load_sweep, merge, run_sweep  # noqa: E402

MODULI = {'E20k': 20000.0, 'E40k': 40000.0, 'E80k': 80000.0}


def strain_sized(spec: RunSpec) -> RunSpec:
    labels = dict(spec.labels)
    amplitude = 15.0 * MODULI[labels['stiffness']] / MODULI['E40k']
    return RunSpec(spec.study, spec.labels, spec.scene, merge(dict(spec.overrides), {'actuation': {'amplitude': amplitude}}),
                   spec.duration_s, spec.replace)


def proportional(spec: RunSpec) -> RunSpec:
    return RunSpec(spec.study, spec.labels, spec.scene,
                   merge(dict(spec.overrides), {'actuation': {'desired_radius': 'proportional'}}),
                   spec.duration_s, spec.replace)


def main() -> int:
    _, specs = load_sweep(study.SWEEP)
    start = time.perf_counter()
    ext = [strain_sized(s) for s in specs if s.study == 'external']
    inn = [proportional(s) for s in specs if s.study == 'internal']
    rows_a = study.as_rows(ext, run_sweep(ext))
    rows_b = study.as_rows(inn, run_sweep(inn))
    stored = study.read_table(study.OUT / 'study.csv')
    for r in rows_a + rows_b:
        r['label'] = '/'.join(r[k] for k in ('mantle', 'stiffness', 'routine', 'distribution') if r.get(k))
    wall = time.perf_counter() - start
    lines = [f'# Paper 000 study: experiments on the readings ({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}, '
             f'{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; command '
             f'`.venv/bin/python benchmarks/paper000_experiments.py`, {wall:.0f} s wall)', '',
             'Each experiment changes one reading and keeps every other value of `config/sweeps/paper000_study.yaml`; '
             'the finding rules are the study\'s. Not the study: its values stay as chosen.', '']
    for title, rows, keep in (('A. Cable load as a strain: 15 N x E / 40 kPa (10 N at 20 kPa ... 30 N at 80 kPa)',
                               rows_a, 'internal'),
                              ('B. Muscle desired radius `proportional` instead of `constant_depth`', rows_b, 'external')):
        lines += [f'## {title}', '']
        for coupling in ('paper', 'consistent'):
            group = [r for r in rows if r['coupling'] == coupling]
            group += [r for r in stored if r['coupling'] == coupling and r['study'] == keep]
            lines += [f'### Coupling `{coupling}`', '', '| finding | reproduced | what the runs show |', '|---|---|---|']
            for claim, _, ok, detail in study.findings(group):
                if claim.startswith(('external' if keep == 'internal' else 'internal')):
                    lines.append(f'| {claim} | {"yes" if ok else "no"} | {detail} |')
            lines.append('')
        faults = [r for r in rows if r['fault']]
        lines += [f'Faults: {len(faults)}'] + [f'- {r["run"]}: {r["fault"]}' for r in faults] + ['']
    text = '\n'.join(lines)
    (study.OUT / 'experiments.md').write_text(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
