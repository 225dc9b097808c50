"""
Experiments explaining the paper 000 study's misses (benchmarks/results/paper000_study/README.md).

Not the study: its values stay as chosen; each experiment changes one reading of the lost text and
reruns the study's finding rules on it, on the study's first version (its routines: 30 % / 45 %
half cosines; see FIRST_VERSION_ROUTINES). Writes benchmarks/results/paper000_study/experiments.md.

    .venv/bin/python -m benchmarks.validation.paper000_experiments                           # all
    .venv/bin/python -m benchmarks.validation.paper000_experiments --only fig12_edge,fixed_nozzle

`--only` runs the named experiments and replaces (or adds) only their sections of experiments.md.
`--version 2` runs them on the study's second version instead (its triangle routines, the stored
`study.csv`; nothing else differs) and writes experiments_v2.md; the first version's file stays.
Runs go one after the other in this process (one core). Experiments marked `refine` also rerun
every case at twice the elements and half the step (the study's REFINED) and store both.

A. strain_load: the cable load read as a strain instead of a force: the pull scales with the
   Young's modulus, 15 N x E / 40 kPa, so every mantle is pulled to about the same deformation
   (findings 1, 2).
B. proportional: the muscle's desired radius read as `proportional` (a uniform fraction of the rest
   radius) instead of `constant_depth` (findings 3, 4, 5).
C. fig12_edge: the muscle's desired radius read as `constant_depth_to_edge`: Fig. 12's function
   "linear (constant) for most of the mantle profile" (section 5.2) held up to the free edge,
   tapered at the pole only, so the muscle narrows the nozzle too (findings 3, 4, 5; both
   couplings).
D. fixed_nozzle: in the paper coupling, the jet leaves through a fixed nozzle of 12.5 mm radius
   (`jet.outlet: free_edge_fixed_nozzle`) instead of the mantle's edge, the edge staying free: the
   authors' later code (github.com/federicorenda/Unified-Multi-soft-body-Dynamics, octopus_driver.m
   `Rn = 12.5e-3; Area_out = pi*Rn.^2`, used unchanged in octopus_derivatives.m's thrust) keeps the
   exit area fixed whatever the shell does (findings 1, 2; external cases, paper coupling).
E. authors_code: the authors' code as written (`coupling: paper_code`, docs/theory/shell.md
   "Experiment E"): pole clamped and edge free, fixed 12.5 mm nozzle, a refilling force, thrust +
   refill + body drag as a uniform axial load on the wall, added mass 1.1 x the shell's own mass in
   every translation, the shell's inertia in the vehicle's frame; all 54 cases of the study's
   `paper` coupling (36 external, 18 internal) (all findings).
F. elastic_wall: the wall's Kelvin-Voigt viscosity a tenth of the study's (`eta_v` = 50 Pa s
   instead of the authors' code's 500 Pa s; 0 crumples at the mesh scale), nearly the limit most
   favourable to a resonance (docs/theory/shell.md, "Experiment F";
   findings 3, 4, 5; internal cases, paper coupling). F.1, the mantles' free breathing, is
   benchmarks/validation/paper000_breathing.py.
I. internal_inertia: the water inside the mantle carries the inertia of paper 001's
   one-dimensional internal flow (`fluid.internal_inertia: one_dimensional`: kinetic energy
   1/2 rho Lambda V'^2, docs/theory/shell.md "Experiment I"); all 54 cases, both couplings
   (all findings).
J. internal_inertia_deforming: as I, with Lambda of the current shape instead of the reference
   (`one_dimensional_deforming`): the water resists a shape that narrows its way out while it flows
   (docs/theory/shell.md "Experiment J"; all 54 cases, both couplings; all findings).
K. internal_momentum: as I, with that flow's momentum relative to the body too
   (`fluid.internal_flow_momentum: true`: rho S V', S = int V_b/V dz; the vehicle feels
   -rho S V'', in the consistent coupling the wall the pressure -rho S U'; docs/theory/shell.md
   "Experiment K"; all 54 cases, both couplings; all findings).
H. hoop_tension: the muscle as the authors' code drives it, an active hoop tension of 15 N/m
   times the routine's triangle on every section of the mantle (`zetas2_a = [0;0;0;0;0;-Ten]`,
   octopus_derivatives.m), instead of the study's desired-radius muscle: a radial pull of
   2 pi 15 N/m per metre of reference meridian, the `uniform` cable (docs/theory/shell.md,
   "Experiment H"; findings 3, 4, 5; internal cases, both couplings).

Every run of an experiment is also stored, row by row in the study's columns, in
`<key>.csv` (and `<key>_refined.csv`) beside its markdown (under `experiments_v2/` for
`--version 2`), so that a test can rerun one case against its stored row.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import datetime
import math
import os
from pathlib import Path
import platform
import sys
import time
from typing import Callable


from benchmarks.validation import paper000_study as study
from pulsejet_sim.studies.sweep import load_sweep, merge, run_one, RunRow, RunSpec

MODULI = {'E20k': 20000.0, 'E40k': 40000.0, 'E80k': 80000.0}
# Experiments A-F ran on the study's first version, whose routines were 30 % / 45 % half cosines
# (config/sweeps/paper000_study.yaml, "pulse"; benchmarks/results/paper000_study/first_version/).
# They are rerun on it: its routines over the second version's values (the only difference), and
# compared with its stored table.
FIRST_VERSION_ROUTINES = {
    'T0.53': {'frequency_hz': 1.8868, 'contraction_s': 0.159, 'release_s': 0.2385},
    'T0.66': {'frequency_hz': 1.5152, 'contraction_s': 0.198, 'release_s': 0.297},
    'T0.79': {'frequency_hz': 1.2658, 'contraction_s': 0.237, 'release_s': 0.3555},
}
FIRST_VERSION_TABLE = study.OUT / 'first_version' / 'study.csv'
COUPLINGS = ('paper', 'consistent')


def changed(spec: RunSpec, override: dict) -> RunSpec:
    return RunSpec(
        spec.study,
        spec.labels,
        spec.scene,
        merge(dict(spec.overrides), override),
        spec.duration_s,
        spec.replace,
    )


def first_version(spec: RunSpec) -> RunSpec:
    routine = FIRST_VERSION_ROUTINES[dict(spec.labels)['routine']]
    return changed(spec, {'actuation': dict(routine, pulse='half_cosine')})


def strain_sized(spec: RunSpec) -> RunSpec:
    amplitude = 15.0 * MODULI[dict(spec.labels)['stiffness']] / MODULI['E40k']
    return changed(spec, {'actuation': {'amplitude': amplitude}})


def proportional(spec: RunSpec) -> RunSpec:
    return changed(spec, {'actuation': {'desired_radius': 'proportional'}})


def to_edge(spec: RunSpec) -> RunSpec:
    return changed(spec, {'actuation': {'desired_radius': 'constant_depth_to_edge'}})


def fixed_nozzle(spec: RunSpec) -> RunSpec:
    return changed(spec, {'jet': {'outlet': 'free_edge_fixed_nozzle', 'outlet_radius_m': 0.0125}})


def elastic_wall(spec: RunSpec) -> RunSpec:
    # 0 was the first choice; with it a mantle crumples at the mesh scale and stops (see the doc)
    return changed(spec, {'material': {'viscosity_pa_s': 50.0}})


def authors_code(spec: RunSpec) -> RunSpec:
    return changed(
        spec,
        {
            'coupling': 'paper_code',
            'jet': {'outlet': 'free_edge_fixed_nozzle', 'outlet_radius_m': 0.0125},
        },
    )


# the authors' code's muscle: `ten = -15*triangularPulse(0,1/2,1,[0 1/2 1])` (octopus_driver.m),
# an active hoop stress resultant in N per metre of reference meridian
CODE_HOOP_TENSION_N_M = 15.0


def hoop_tension(spec: RunSpec) -> RunSpec:
    """
    Replace the muscle of a study's internal case by the code's active hoop tension.

    A hoop resultant T on a strip of reference meridian dX does work -2 pi T dX r' (the ring's
    circumference is 2 pi r): an inward radial force 2 pi T per metre of meridian, whatever the
    wall's stiffness or shape. That is the `uniform` cable (its work-equivalent nodal shares: equal
    per interior node, half at a free edge, the pole's half to the axis) with a total pull of 2 pi
    T times the reference meridian length; the routine's period and triangle stay the study's
    (the same line of the code gives both).
    """
    from pulsejet_sim.scene import load_scene

    model = load_scene(spec.scene, dict(spec.overrides), replace=spec.replace).model
    keep = ('source', 'frequency_hz', 'contraction_s', 'release_s', 'start_delay_s', 'pulse')
    muscle = spec.overrides['actuation']
    actuation = {k: muscle[k] for k in keep if k in muscle}
    actuation.update(
        kind='cable',
        distribution='uniform',
        amplitude=2.0 * math.pi * CODE_HOOP_TENSION_N_M * model.ref.length_m,
    )
    overrides = dict(spec.overrides, actuation=actuation)
    return RunSpec(
        spec.study, spec.labels, spec.scene, overrides, spec.duration_s, spec.replace
    )


def internal_inertia(spec: RunSpec) -> RunSpec:
    return changed(spec, {'fluid': {'internal_inertia': 'one_dimensional'}})


def internal_inertia_deforming(spec: RunSpec) -> RunSpec:
    return changed(spec, {'fluid': {'internal_inertia': 'one_dimensional_deforming'}})


def internal_momentum(spec: RunSpec) -> RunSpec:
    return changed(
        spec, {'fluid': {'internal_inertia': 'one_dimensional', 'internal_flow_momentum': True}}
    )


@dataclass(frozen=True)
class Experiment:
    letter: str
    title: str
    study: str  # which of the study's cases it reruns ('both': external and internal)
    change: Callable[[RunSpec], RunSpec]
    couplings: tuple[str, ...]
    refine: bool  # rerun every case at study.REFINED and store both
    note: str = ''


EXPERIMENTS = {
    'strain_load': Experiment(
        'A',
        'Cable load as a strain: 15 N x E / 40 kPa (10 N at 20 kPa ... 30 N at 80 kPa)',
        'external',
        strain_sized,
        COUPLINGS,
        False,
    ),
    'proportional': Experiment(
        'B',
        'Muscle desired radius `proportional` instead of `constant_depth`',
        'internal',
        proportional,
        COUPLINGS,
        False,
    ),
    'fig12_edge': Experiment(
        'C',
        'Muscle desired radius `constant_depth_to_edge` instead of `constant_depth` (Fig. 12 held '
        'up to the edge)',
        'internal',
        to_edge,
        COUPLINGS,
        True,
        'Reading: section 5.2 says "the desired radius function is linear (constant) for most of '
        'the mantle profile and thus more attuned with the linear conical profile", and the '
        'introduction "The contraction of the mantle is ensured by a network of circular muscles '
        'symmetrically arranged all around the body". The study\'s `constant_depth` tapers the '
        'function to zero over 15 % of the meridian at both ends, so the muscle never narrows the '
        'free edge (the nozzle). Here the function keeps its constant depth (25 % of the largest '
        "radius) up to the edge and tapers at the pole only (where the cone's rounded tip and the "
        'ellipsoid\'s pole cannot take a constant depth): "most of the mantle profile" is read as '
        "all but the pole. Everything else is the study's; the 18 internal cases in both "
        'couplings.',
    ),
    'fixed_nozzle': Experiment(
        'D',
        'Paper coupling: a fixed 12.5 mm nozzle (`jet.outlet: free_edge_fixed_nozzle`) instead of '
        'the mantle edge',
        'external',
        fixed_nozzle,
        ('paper',),
        True,
        'Reading: paper 000 gives no exit-area equation ("The outflow speed is given by: where" '
        "lost) and no minimum opening. The authors' later code of the same shell "
        '(github.com/federicorenda/Unified-Multi-soft-body-Dynamics, `octopus_driver.m`: `Rn = '
        '12.5e-3; % [m] Raggio Nuzzle`, `Area_out = pi*Rn.^2`; `octopus_derivatives.m`: '
        '`mod_thrust = '
        '-sign(Vol_punto)*(ro_water*Vol_punto^2)*((Vol_punto<0)*Cf/(Area_out*Aream)+...)`) uses a '
        "fixed exit area whatever the shell does, leaves the shell's open end free (its "
        '"condizioni su X=L" are zero-stress) and puts no cavity pressure on the wall. So only '
        'the exit area changes here: the edge stays free as in the study, the jet leaves through '
        'a fixed nozzle of 12.5 mm radius (for the ellipsoid its opening at rest, for the cone a '
        "nozzle inside its 30 mm edge), the inlet is the code's `Area_out + 3*pi*Rb.^2`, Rb = 10 "
        "mm (the model's default). The 36 external cases in the paper coupling (the consistent "
        'coupling already stops the wall before the nozzle shuts).',
    ),
    'authors_code': Experiment(
        'E',
        "The authors' code as written (`coupling: paper_code`) in place of the `paper` coupling",
        'both',
        authors_code,
        ('paper',),
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment E: the authors\' '
        'code", with the code\'s lines quoted, before any run): the six places where the study\'s '
        "`paper` coupling departs from the authors' public code of the same shell "
        '(github.com/federicorenda/Unified-Multi-soft-body-Dynamics, commit 2cabfe59, '
        '`octopus_driver.m`, `octopus_derivatives.m`), adopted together: (1) the polar cap up to '
        'the first node whose wall has turned by pi/4 is rigid, part of the body, its rim clamped '
        '(first version, the pole node alone, stopped after 5 runs: see the doc) and the open '
        'edge is free in r, z and theta (`sigmas_o = zeros(6,1)` at X = 0, the "buco anteriore"; '
        'zero-stress "condizioni su X=L"); (2) a fixed 12.5 mm nozzle, `Area_out = pi*Rn.^2`, '
        "`Area_in = Area_out+3*pi*Rb.^2`; (3) a refilling force `-Cf rho V'^2/A_in` "
        '(`(Vol_punto>0)*Cf/(Area_in*Aream)`); (4) thrust, refilling force and body drag as a '
        'uniform axial load per reference area on the wall (`fluid = mod_fluid*[senth;costh;0]`, '
        '`zetas_e = [0;0;0;fluid]`), reaching the vehicle only through the clamped rim '
        '(`F_is1r`); no cavity pressure, no tangential drag on the wall; (5) added mass 1.1 x the '
        "shell's own mass in r and z (`Gammas_ag = Gammas+ro_shel*B*diag([0 0 0 2*h 2*h 2*h])`); "
        "(6) the shell's inertia sees the vehicle's acceleration (`- sigmar_bar_punto`), the "
        "vehicle solved with the shell. Every study value stays (the code's actuation, masses, "
        "geometry and head drag are not adopted; the study's internal water and ram stay). The 54 "
        "cases of the study's `paper` coupling (36 external, 18 internal), all five findings; "
        "runs keep the study's names (`.../paper/...`).",
    ),
    'elastic_wall': Experiment(
        'F',
        "The wall's viscosity a tenth (`eta_v` = 50 instead of 500 Pa s): can an ellipsoid "
        'resonate?',
        'internal',
        elastic_wall,
        ('paper',),
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment F", before any '
        "run): the study's wall is a Kelvin-Voigt solid with `eta_v` = 500 Pa s (the authors' "
        'code; '
        'paper 000 gives no value); the estimated damping ratio of the breathing mode, '
        '`3 eta_v omega_n / (2 E)`, is 1.8, 1.3, 0.9 at 20, 40, 80 kPa, so no resonant peak can '
        "exist. Here the wall's viscosity is a tenth of it (estimated damping ratio 0.18, 0.13, "
        '0.09; the first choice, 0, lets the wall crumple at the mesh scale and stop); '
        "everything else is the study's. The 18 internal cases of the `paper` coupling; the "
        'free breathing of the mantles (F.1) is in breathing.md.',
    ),
    'hoop_tension': Experiment(
        'H',
        "The muscle as the authors' code drives it: an active hoop tension of 15 N/m, not a "
        'desired radius',
        'internal',
        hoop_tension,
        COUPLINGS,
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment H", before any '
        'run): paper 000 section 5.2 drives the muscle through a desired-radius function (Fig. '
        "12, curves lost); the authors' public code of the same shell drives it with an active "
        'hoop tension, `ten = -15*triangularPulse(0,1/2,1,[0 1/2 1])` (octopus_driver.m), '
        '`Ten = interp1([0 1/2 1],ten,mod(t,per)/per)` and `zetas2_a = [0;0;0;0;0;-Ten]` '
        'subtracted from the hoop wrench `zetas2_i` of every section ii = 2..nsezs '
        '(octopus_derivatives.m): 15 N/m at the peak, the same on every section, whatever the '
        "wall's stiffness. On a ring of reference meridian dX it pulls inwards with 2 pi T dX, "
        "so here the study's muscle becomes the `uniform` cable (equal per metre of reference "
        'meridian, the free edge included) of total pull 2 pi 15 N/m x the meridian length '
        "(the study's cone 13.9 cm: 13.1 N; ellipsoid 16.7 cm: 15.7 N), with the study's "
        'triangle and '
        "periods (the code's own). Everything else is the study's; the 18 internal cases in "
        'both couplings.',
    ),
    'internal_inertia': Experiment(
        'I',
        "The water inside carries the inertia of paper 001's one-dimensional internal flow",
        'both',
        internal_inertia,
        COUPLINGS,
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment I", before any '
        "study run): paper 000's wall loads are drag and an added mass \"representing the load "
        'locally exerted by pressure" (eq. (22)); the study\'s added mass is the outer '
        "water's, local. The water inside, which must leave through the mantle's opening, gets "
        "the kinetic energy of paper 001's internal flow (section 3.4, eqs. 4-6: the flux "
        "through a section is the volume behind it), `1/2 rho Lambda V'^2` with `Lambda = int "
        '(V_b(z)/V)^2 / (pi r^2) dz` over the reference cavity (cone 11.1 /m, ellipsoid 34.6 /m); '
        "by Lagrange's equation a uniform pressure `-rho Lambda V''` on the inner wall (and, "
        'in the consistent coupling, on the vehicle through the frame). Everything else is the '
        "study's; all 54 cases in both couplings.",
    ),
    'internal_inertia_deforming': Experiment(
        'J',
        "The water inside as in I, its inertance taken on the mantle's current shape",
        'both',
        internal_inertia_deforming,
        COUPLINGS,
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment J", before any '
        "study run): experiment I's internal flow with `Lambda = int (V_b/V)^2 / (pi r^2) dz` "
        'taken on the current shape instead of the reference one (paper 001 builds its internal '
        "flow on the ellipsoid's current sections, `A(x) = pi b^2 (1 - x^2)`, eqs. 4-6), "
        'because the independent review of I found the constant `Lambda` least faithful where '
        "the mantle's edge, the nozzle, closes. By Lagrange's equation the wall feels "
        "`-rho (Lambda V')' grad V - 1/2 rho V'^2 grad Lambda`. Everything else is the study's; "
        'all 54 cases in both couplings.',
    ),
    'internal_momentum': Experiment(
        'K',
        "The water inside as in I, with that flow's momentum relative to the body",
        'both',
        internal_momentum,
        COUPLINGS,
        True,
        'Reading (decided and written into docs/theory/shell.md, "Experiment K", before any '
        "study run): experiment I's one-dimensional flow also carries the momentum "
        "`rho S V'` relative to the body along +z, `S = int V_b/V dz` over the reference cavity "
        '(ellipsoid 0.0732 m, cone 0.0395 m): the momentum balance of the body and the water '
        "inside is `d/dt[(M + m_x + rho V) U + rho S V'] = T - D - ram`, of which the rocket "
        "equation is the steady case. The vehicle feels `-rho S V''`; in the consistent "
        "coupling the wall also feels the uniform pressure `-rho S U'` (Lagrange's equation of "
        "the cross term `rho S U V'`); in the paper coupling the wall's body frame has no such "
        "force and the ledger books the vehicle force's work as created. Everything else is "
        "I's (the study's values with `internal_inertia: one_dimensional`); all 54 cases in "
        'both couplings.',
    ),
}


def measure(spec: RunSpec) -> RunRow:
    """
    Measure sweep.run_one's metrics plus the smallest radius of the mantle's edge node.

    The metrics are the study's columns, computed by sweep.run_one; the radius is the smallest of
    the mantle's edge node over the run.
    """
    edge = []
    model = None

    def edge_radius(sim) -> None:
        nonlocal model
        model = sim.model
        edge.append(float(model.profile(sim.state)[0][-1]))

    row = run_one(spec, edge_radius)
    if row.metrics:
        row.metrics['edge_radius_min_m'] = min(edge)
        row.metrics['edge_radius_rest_m'] = float(model.profile(model.initial_state())[0][-1])
    return row


def run_all(specs: list[RunSpec]) -> list[dict]:
    rows = []
    for i, spec in enumerate(specs):
        res = measure(spec)
        row = study.as_rows([spec], [res])[0]
        for k in ('edge_radius_min_m', 'edge_radius_rest_m'):
            row[k] = res.metrics.get(k, float('nan'))
        row['label'] = '/'.join(
            row[k] for k in ('mantle', 'stiffness', 'routine', 'distribution') if row.get(k)
        )
        rows.append(row)
        print(
            f'{i + 1}/{len(specs)} {spec.name}: {row["peak_speed_m_s"]:.4g} m/s {res.fault or ""}',
            file=sys.stderr,
            flush=True,
        )
    return rows


def verdicts(rows, stored, keep, coupling, prefix):
    group = [r for r in rows if r['coupling'] == coupling]
    group += [r for r in stored if r['coupling'] == coupling and r['study'] == keep]
    return [f for f in study.findings(group) if f[0].startswith(prefix)]


def section(
    key: str,
    exp: Experiment,
    specs: list[RunSpec],
    stored: list[dict],
    command: str = '-m benchmarks.validation.paper000_experiments',
    table_dir: Path | None = None,
) -> str:
    start = time.perf_counter()
    cases = [
        exp.change(s)
        for s in specs
        if exp.study in ('both', s.study) and dict(s.labels)['coupling'] in exp.couplings
    ]
    rows = run_all(cases)
    fine = run_all([study.refined(s) for s in cases]) if exp.refine else []
    # a run whose refined value moved by more than study.CONVERGED is run once more, at twice the
    # refined elements and half its step, to show which of the two is converged
    loose = [
        i
        for i, (r, f) in enumerate(zip(rows, fine))
        if abs(r['peak_speed_m_s'] / f['peak_speed_m_s'] - 1.0) > study.CONVERGED
    ]
    finer = dict(zip(loose, run_all([changed(cases[i], study.FINER) for i in loose])))
    wall = time.perf_counter() - start
    if table_dir is not None:
        table_dir.mkdir(parents=True, exist_ok=True)
        study.write_table(rows, table_dir / f'{key}.csv')
        if fine:
            study.write_table(fine, table_dir / f'{key}_refined.csv')
    keep = {'external': 'internal', 'internal': 'external'}.get(exp.study, '')
    prefix = '' if exp.study == 'both' else exp.study
    lines = [f'## {exp.letter}. {exp.title}', '']
    if exp.refine:
        lines += [
            f'Experiment `{key}` '
            f'({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}, '
            f'{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; '
            f'command `.venv/bin/python {command} --only {key}`, '
            f'one process, {wall:.0f} s wall; '
            f"{len(cases)} runs at the study's 96 elements / 0.5 ms and again at 192 / 0.25 ms).",
            '',
        ]
    if exp.note:
        lines += [exp.note, '']
    for coupling in exp.couplings:
        mine = verdicts(rows, stored, keep, coupling, prefix)
        lines += [f'### Coupling `{coupling}`', '']
        if exp.refine:
            base = verdicts(
                [r for r in stored if exp.study in ('both', r['study'])],
                stored,
                keep,
                coupling,
                prefix,
            )
            refined = verdicts(fine, stored, keep, coupling, prefix)
            lines += [
                '| finding | study (stored) | this reading | this reading, refined (192 el., 0.25 '
                'ms) |',
                '|---|---|---|---|',
            ]
            for (claim, _, ok0, d0), (_, _, ok, d), (_, _, okf, df) in zip(base, mine, refined):
                lines.append(
                    f'| {claim} | {"yes" if ok0 else "no"}: {d0} | {"yes" if ok else "no"}: {d} | '
                    f'{"yes" if okf else "no"}: {df} |'
                )
        else:
            lines += ['| finding | reproduced | what the runs show |', '|---|---|---|']
            for claim, _, ok, detail in mine:
                lines.append(f'| {claim} | {"yes" if ok else "no"} | {detail} |')
        lines.append('')
    if exp.refine:
        by_name = {r['run']: r for r in stored}
        errors = [abs(r['peak_speed_m_s'] / f['peak_speed_m_s'] - 1.0) for r, f in zip(rows, fine)]
        lines += [
            '### Runs and resolution',
            '',
            'Peak speed of each run against the same run at twice the elements and half the step: '
            f'largest error {max(errors) * 100:.2f} %, '
            f'median {sorted(errors)[len(errors) // 2] * 100:.2f} %; '
            f'{sum(e > study.CONVERGED for e in errors)} of {len(errors)} '
            f'above {study.CONVERGED * 100:g} %. '
            "Edge radius: the smallest radius of the mantle's free edge over the run, over its "
            'radius at rest.',
            '',
            '| run | study peak (m/s) | peak (m/s) | refined peak (m/s) | error | peak thrust (N) '
            '| edge min / rest (mm) | ledger closure |',
            '|---|---|---|---|---|---|---|---|',
        ]
        for r, f, e in zip(rows, fine, errors):
            base = by_name.get(r['run'])
            lines.append(
                f'| {r["run"]} | {base["peak_speed_m_s"]:.4g} | {r["peak_speed_m_s"]:.4g} | '
                f'{f["peak_speed_m_s"]:.4g} | {e * 100:.2f} % | {r["peak_thrust_n"]:.3g} | '
                f'{r["edge_radius_min_m"] * 1e3:.2f} / {r["edge_radius_rest_m"] * 1e3:.2f} | '
                f'{r["closure_relative"]:.1e} |'
            )
        lines.append('')
        if finer:
            lines += ['Runs above 2 %, once more at 384 elements / 0.125 ms:', '']
            for i, f3 in finer.items():
                f2 = fine[i]['peak_speed_m_s']
                lines.append(
                    f'- {rows[i]["run"]}: {rows[i]["peak_speed_m_s"]:.4g} (96 el.) / '
                    f'{f2:.4g} (192 el.) / '
                    f'{f3["peak_speed_m_s"]:.4g} m/s (384 el.): the 192-element value is '
                    f'{abs(f2 / f3["peak_speed_m_s"] - 1.0) * 100:.2f} % from the finest'
                )
            lines.append('')
    faults = [r for r in rows + fine + list(finer.values()) if r['fault']]
    lines += [f'Faults: {len(faults)}'] + [f'- {r["run"]}: {r["fault"]}' for r in faults] + ['']
    return '\n'.join(lines)


def split_sections(text: str) -> tuple[str, dict[str, str]]:
    """Split experiments.md into its preamble and its '## X. ...' sections, keyed by letter."""
    parts = text.split('\n## ')
    sections = {}
    for part in parts[1:]:
        sections[part.split('.', 1)[0]] = '## ' + part.rstrip('\n') + '\n'
    return parts[0].rstrip('\n') + '\n', sections


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument(
        '--only', default='', help='comma-separated experiments: ' + ', '.join(EXPERIMENTS)
    )
    parser.add_argument(
        '--version',
        type=int,
        choices=(1, 2),
        default=1,
        help="the study version to change one reading of (default 1, the experiments' first run)",
    )
    args = parser.parse_args(argv)
    keys = [k for k in args.only.split(',') if k] or list(EXPERIMENTS)
    unknown = [k for k in keys if k not in EXPERIMENTS]
    if unknown:
        parser.error(
            f'--only: unknown experiment(s) {", ".join(unknown)}; '
            f'allowed: {", ".join(EXPERIMENTS)}'
        )
    _, specs = load_sweep(study.SWEEP)
    if args.version == 1:
        specs = [first_version(s) for s in specs]
        stored = study.read_table(FIRST_VERSION_TABLE)
        path = study.OUT / 'experiments.md'
        version_text = (
            "All of them ran on the study's first version (routines of 30 % / 45 % half cosines, "
            "`first_version/`), and 'study (stored)' is that version's table."
        )
    else:
        stored = study.read_table(study.OUT / 'study.csv')
        path = study.OUT / 'experiments_v2.md'
        version_text = (
            "All of them ran on the study's second version (the authors' code's triangle "
            "routines, the study as stored), and 'study (stored)' is its `study.csv`."
        )
    command = '-m benchmarks.validation.paper000_experiments' + (
        ' --version 2' if args.version == 2 else ''
    )
    start = time.perf_counter()
    new = {
        EXPERIMENTS[k].letter: section(
            k, EXPERIMENTS[k], specs, stored, command, path.with_suffix('')
        )
        for k in keys
    }
    if len(keys) == len(EXPERIMENTS) or not path.exists():
        now = f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}'
        preamble = (
            '# Paper 000 study: experiments on the readings\n\n'
            f'All experiments: {now}, {platform.machine()}, '
            f'{os.cpu_count()} cores, Python {platform.python_version()}; command '
            f'`.venv/bin/python {command}`, '
            f'{time.perf_counter() - start:.0f} s wall '
            '(an experiment rerun alone with `--only` states its own run in its section).\n\n'
            'Each experiment changes one reading and keeps every other value of '
            "`config/sweeps/paper000_study.yaml`; the finding rules are the study's. "
            f'Not the study: its values stay as chosen. {version_text}\n'
        )
        sections = {}
    else:
        preamble, sections = split_sections(path.read_text())
    sections.update(new)
    text = preamble + '\n' + '\n'.join(sections[k] for k in sorted(sections))
    path.write_text(text)
    print('\n'.join(new[k] for k in sorted(new)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
