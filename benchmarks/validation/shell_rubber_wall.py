"""
Numerical experiment (not a fitted change): the shipped shell robots with a neo-Hookean wall.

The shell's ``material.law: neo_hookean`` (docs/theory/shell_rubber.md) replaces the wall's
membrane energy by an incompressible neo-Hookean sheet's. Here the shipped cable robot
``shell_robot`` (and the muscle-driven ``shell_cone``, whose muscle is the law's active strain)
run with the wall switched to it at the same small-strain Young's modulus, mu = E/3, every
other value as shipped. Because the neo-Hookean sheet is incompressible (nu = 1/2) and the
shipped walls have nu = 0, a third run, the linear law at nu = 0.49 (its largest allowed),
separates what the Poisson ratio does from what the nonlinearity does. The escape scenes
(escape*.yaml) are lumped-model scenes, not shell scenes: not run.

Reported per run, over the whole run (samples every 10 ms): the largest and smallest hoop
stretch r/r0 (nodes off the axis) and meridian stretch (element chord over its reference
chord); over the last four routine periods: the mean swimming speed and the volume stroke; the
ledger's closure at the end. Each run is repeated at twice the elements and half the step
(the discretisation's check); the table gives the relative difference of the mean speed, the
smallest hoop stretch and the largest meridian stretch (the extreme ones: no wall here stretches
beyond its rest radius). No shipped scene changes. Writes
benchmarks/results/shell_rubber_wall.md.

    .venv/bin/python -m benchmarks.validation.shell_rubber_wall
"""

from __future__ import annotations

import copy
from pathlib import Path
import sys
import time

from benchmarks import common
import numpy as np
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.core.schema import read_yaml_file
from pulsejet_sim.models.shell.model import ShellModel

ROOT = Path(__file__).resolve().parents[2]
SCENES = ('shell_robot', 'shell_cone')
SAMPLE_S = 0.01
PERIODS = 4  # the mean speed and the stroke: over the last four routine periods


def variant(scene: dict, law: str) -> dict:
    """Return the scene with the wall's law: shipped, linear at nu = 0.49, or neo-Hookean."""
    out = copy.deepcopy(scene)
    mat = out['material']
    if law == 'linear_nu_0.49':
        mat['poisson_ratio'] = 0.49
    elif law == 'neo_hookean':
        young = float(mat.pop('youngs_modulus_pa'))
        mat.pop('poisson_ratio')
        mat.update(law='neo_hookean', shear_modulus_pa=young / 3.0)
    return out


def finer(scene: dict) -> dict:
    """Return the scene at twice the elements and half the step."""
    out = copy.deepcopy(scene)
    out['mesh']['elements'] = 2 * int(out['mesh']['elements'])
    out['simulation']['dt_s'] = 0.5 * float(out['simulation']['dt_s'])
    return out


def run(scene: dict) -> dict:
    """Run the scene for its duration; return the stretches, speed, stroke and closure."""
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    per = max(1, int(round(SAMPLE_S / model.dt_s)))
    n = int(round(model.duration_s / (per * model.dt_s)))
    r0, ds = model.ref.r0, model.E[:, 0]
    hoop = [np.inf, -np.inf]
    meridian = [np.inf, -np.inf]
    speed, volume = [], []
    for k in range(n):
        model.advance(state, k * per * model.dt_s, per, Command())
        r, z = model.profile(state)
        h = r[1:] / r0[1:]
        m = np.hypot(np.diff(r), np.diff(z)) / ds
        hoop = [min(hoop[0], h.min()), max(hoop[1], h.max())]
        meridian = [min(meridian[0], m.min()), max(meridian[1], m.max())]
        obs = model.observe(state, (k + 1) * per * model.dt_s, Command())
        speed.append(obs.velocity_m_s)
        volume.append(obs.volume_m3)
    last = int(round(PERIODS / float(scene['actuation']['frequency_hz']) / (per * model.dt_s)))
    return {
        'hoop': hoop,
        'meridian': meridian,
        'speed': float(np.mean(speed[-last:])),
        'stroke': float(np.ptp(volume[-last:])),
        'closure': model.energy_ledger(state)['closure_relative'],
    }


def main() -> int:
    lines = [
        common.header('Shell robots with a neo-Hookean wall (a numerical experiment)',
                      'python -m benchmarks.validation.shell_rubber_wall').rstrip('\n'),
        '',
        "Not a fitted change: the shipped scenes with only the wall's law switched, at the same "
        "small-strain Young's modulus (neo_hookean: mu = E/3; linear nu = 0.49: the Poisson "
        'effect alone). Stretches over the whole run; speed and stroke over the last '
        f'{PERIODS} periods; "finer": the relative difference at twice the elements and half '
        'the step. Method: the docstring of benchmarks/validation/shell_rubber_wall.py.',
        '',
        '| scene | wall | hoop stretch min-max | meridian stretch min-max | mean speed, m/s '
        '| vs shipped | stroke, ml | closure | finer: speed, min hoop, max meridian |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    start = time.perf_counter()
    for name in SCENES:
        shipped = read_yaml_file(ROOT / 'config' / f'{name}.yaml')
        base = None
        for law in ('shipped', 'linear_nu_0.49', 'neo_hookean'):
            scene = variant(shipped, law)
            res = run(scene)
            fine = run(finer(scene))
            base = res['speed'] if base is None else base
            wall = {'shipped': f'linear, nu = {shipped["material"]["poisson_ratio"]}',
                    'linear_nu_0.49': 'linear, nu = 0.49',
                    'neo_hookean': 'neo-Hookean, mu = E/3'}[law]
            lines.append(
                f'| {name} | {wall} | {res["hoop"][0]:.3f}-{res["hoop"][1]:.3f} '
                f'| {res["meridian"][0]:.3f}-{res["meridian"][1]:.3f} | {res["speed"]:.4f} '
                f'| {100 * (res["speed"] / base - 1):+.1f} % | {res["stroke"] * 1e6:.1f} '
                f'| {res["closure"]:.1e} '
                f'| {100 * (fine["speed"] / res["speed"] - 1):+.2f} %, '
                f'{100 * (fine["hoop"][0] / res["hoop"][0] - 1):+.2f} %, '
                f'{100 * (fine["meridian"][1] / res["meridian"][1] - 1):+.2f} % |'
            )
            print(lines[-1], flush=True)
    lines += ['', f'Wall time {time.perf_counter() - start:.0f} s.', '']
    out = ROOT / 'benchmarks' / 'results' / 'shell_rubber_wall.md'
    out.write_text('\n'.join(lines))
    print(f'written to {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
