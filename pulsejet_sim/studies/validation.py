"""
`pulsejet validate [CASE...]`: predicted against measured figures of real robots.

A case (validation/cases/*.yaml, keys in validation/README.md) names a scene, the measured
figures with their source, how each is computed from a run, and its tolerance. This module runs
each case through the public APIs (load_scene, Simulation, the scene's routine), reads the
figures from samples of the run, books the energy budget from the model's ledger over the case's
interval beside what the measured figures imply, reruns the case on finer discretisations to show
the figures converged (a lumped case at dt/2 and dt/4; a shell case: validation_convergence, the
plan in validation/convergence_plan.md), runs the case's probes (numerical experiments, not
predictions), and writes docs/validation/: report.md (tables), results.json (the stored rows a
test reruns) and one PNG per case (the predicted time series with the measured figures marked).

One command regenerates everything: ``pulsejet validate`` (all cases; a subset updates only its
own entries in results.json and rewrites the report from all stored entries).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import datetime
import json
import math
from pathlib import Path
import platform
import sys
from typing import Any, Sequence

import numpy as np
from pulsejet_sim.core.model_io import SimulationBlowUp
from pulsejet_sim.core.schema import read_yaml_file, YAMLInputError
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene, merge, SceneError

ROOT = Path(__file__).resolve().parents[2]
CASES_DIR = ROOT / 'validation' / 'cases'
POSTHOC_FILE = ROOT / 'validation' / 'posthoc.yaml'
OUT_DIR = ROOT / 'docs' / 'validation'
COMMAND = 'pulsejet validate'

QUANTITIES = (
    'mean_velocity',
    'max_velocity',
    'max_acceleration',
    'time_of_max_velocity',
    'volume_range',
    'deflation_90_time',
)
COMPARISONS = ('value', 'at_least', 'at_most')
STATUSES = ('predicted', 'fitted', 'fitted_upstream')
PROTOCOLS = ('steady', 'from_rest')
# ledger keys read as cumulative flows (their change over the interval is what it booked) and as
# stored energies (their change is what the interval left in them)
FLOW_KEYS = ('in_actuation_work', 'out_jet_kinetic', 'out_drag', 'out_viscous', 'out_other')
STORED_KEYS = (
    'stored_elastic',
    'stored_kinetic_vehicle',
    'stored_kinetic_outer_fluid',
    'stored_kinetic_internal',
)
LABELS = {
    'in_initial': 'stored at t = 0 (input)',
    'in_actuation_work': 'actuator work (input)',
    'out_jet_kinetic': 'jet kinetic energy (out)',
    'out_drag': 'drag work (out)',
    'out_viscous': 'viscous dissipation (out: wall, shell; nozzle, lumped)',
    'out_other': 'other losses (out: exit, valve, inflow mixing)',
    'stored_elastic': 'elastic energy',
    'stored_kinetic_vehicle': 'vehicle kinetic energy',
    'stored_kinetic_outer_fluid': 'outer water kinetic energy',
    'stored_kinetic_internal': 'water inside, kinetic energy',
    'created_total': 'created by the equations (sum of created_*; not an input)',
}


class ValidationCaseError(ValueError):
    """A case file that cannot be read or is not a valid case (the message names the key)."""


# ---------------------------------------------------------------------------------------------
# case files


def case_paths(names: Sequence[str] = (), cases_dir: Path = CASES_DIR) -> list[Path]:
    """Case files by id (file stem) or path; all cases under cases_dir when names is empty."""
    if not names:
        paths = sorted(cases_dir.glob('*.yaml'))
        if not paths:
            raise ValidationCaseError(f'no case files (*.yaml) under {str(cases_dir)!r}')
        return paths
    known = sorted(p.stem for p in cases_dir.glob('*.yaml'))
    out = []
    for name in names:
        path = Path(name)
        if path.suffix in ('.yaml', '.yml') and path.is_file():
            out.append(path)
        elif (cases_dir / f'{name}.yaml').is_file():
            out.append(cases_dir / f'{name}.yaml')
        else:
            raise ValidationCaseError(
                f'validation case {name!r} not found; allowed: a case file path or one of '
                f'{", ".join(known)}'
            )
    return out


def _need(mapping: dict, key: str, where: str, kind=None, choices=None) -> Any:
    if not isinstance(mapping, dict) or key not in mapping:
        raise ValidationCaseError(f'{where}: key {key!r} missing')
    value = mapping[key]
    if kind is not None and (not isinstance(value, kind) or isinstance(value, bool)):
        raise ValidationCaseError(
            f'{where}.{key}: {value!r} is not {getattr(kind, "__name__", kind)}'
        )
    if choices is not None and value not in choices:
        raise ValidationCaseError(
            f'{where}.{key}: {value!r} not allowed; allowed: one of {", ".join(choices)}'
        )
    return value


def load_case(path: Path) -> dict:
    """Read and check one case file (yaml.SafeLoader with the project's limits)."""
    try:
        case = read_yaml_file(path, f'validation case {str(path)!r}')
    except YAMLInputError as err:
        raise ValidationCaseError(str(err)) from None
    where = path.stem
    if not isinstance(case, dict):
        raise ValidationCaseError(f'{where}: top level is not a mapping')
    for key in ('id', 'title', 'scene', 'source'):
        _need(case, key, where, str)
    if case['id'] != path.stem:
        raise ValidationCaseError(f'{where}: id {case["id"]!r} differs from the file name')
    run = _need(case, 'run', where, dict)
    _need(run, 'protocol', f'{where}.run', str, PROTOCOLS)
    for key in ('duration_s', 'sample_period_s'):
        value = _need(run, key, f'{where}.run', (int, float))
        if not (math.isfinite(value) and value > 0):
            raise ValidationCaseError(f'{where}.run.{key}: {value!r}; allowed: > 0')
    window = _need(run, 'window', f'{where}.run', dict)
    if 'last_cycles' not in window and not ('from_s' in window and 'to_s' in window):
        raise ValidationCaseError(
            f'{where}.run.window: {window!r}; allowed: last_cycles: N, or from_s and to_s'
        )
    figures = _need(case, 'figures', where, list)
    if not figures:
        raise ValidationCaseError(f'{where}.figures: empty')
    for i, fig in enumerate(figures):
        w = f'{where}.figures[{i}]'
        _need(fig, 'id', w, str)
        _need(fig, 'quantity', w, str, QUANTITIES)
        _need(fig, 'measured', w, (int, float))
        _need(fig, 'unit', w, str)
        _need(fig, 'comparison', w, str, COMPARISONS)
        _need(fig, 'tolerance_relative', w, (int, float))
        _need(fig, 'status', w, str, STATUSES)
        if 'uncertainty' not in fig:
            raise ValidationCaseError(f'{w}: key \'uncertainty\' missing (say "not stated")')
    for i, probe in enumerate(case.get('probes') or []):
        _need(probe, 'id', f'{where}.probes[{i}]', str)
        _need(probe, 'overrides', f'{where}.probes[{i}]', dict)
    overrides = case.get('overrides') or {}
    if not isinstance(overrides, dict):
        raise ValidationCaseError(f'{where}.overrides: {overrides!r} is not a mapping')
    return case


# ---------------------------------------------------------------------------------------------
# one run


@dataclass
class Trace:
    """Samples of one run: time, motion, volume, fluid mass, thrust and drag, ledgers."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    volume: np.ndarray
    fluid_mass: np.ndarray
    thrust: np.ndarray  # N, jet thrust on the vehicle, forward +
    drag: np.ndarray  # N, drag on the vehicle, forward + (negative while swimming forward)
    ledgers: list
    dt_s: float
    fault: str | None
    scene: Any


def run_trace(scene, duration_s: float, sample_period_s: float) -> Trace:
    """Run `scene` from its initial state under its routine (as `pulsejet run` does), sampling."""
    from pulsejet_sim.routines import routine_from_scene

    model = scene.model
    sim = Simulation(model)
    routine = routine_from_scene(scene.routine)
    per = max(1, int(round(sample_period_s / model.dt_s)))
    n_samples = int(math.ceil(duration_s / (per * model.dt_s) - 1e-9))
    obs = sim.observe()
    rows = [obs]
    ledgers = [sim.energy_ledger()]
    fault = None
    for _ in range(n_samples):
        command = routine.command(sim.time_s, obs.volume_m3) if routine else sim.command
        try:
            obs = sim.step(per, command)
        except SimulationBlowUp as err:
            fault = str(err)
            break
        rows.append(obs)
        ledgers.append(sim.energy_ledger())

    def col(name):
        return np.array([getattr(o, name) for o in rows], dtype=float)

    return Trace(
        t=col('time_s'),
        x=col('position_m'),
        v=col('velocity_m_s'),
        a=col('acceleration_m_s2'),
        volume=col('volume_m3'),
        fluid_mass=col('fluid_mass_kg'),
        thrust=col('thrust_n'),
        drag=col('drag_n'),
        ledgers=ledgers,
        dt_s=model.dt_s,
        fault=fault,
        scene=scene,
    )


def actuation_frequency_hz(scene) -> float:
    """Return the cyclic actuation's frequency of a scene, Hz (shell cable or muscle)."""
    act = scene.data.get('actuation') or {}
    freq = act.get('frequency_hz') if isinstance(act, dict) else None
    if freq is None and scene.routine:
        freq = scene.routine.get('frequency_hz')
    if not freq:
        raise ValidationCaseError(
            f'scene {scene.name!r} has no actuation.frequency_hz; a window in last_cycles needs a '
            'cyclic actuation (allowed: from_s/to_s)'
        )
    return float(freq)


def window_of(case: dict, scene, trace_end_s: float) -> tuple[float, float, int]:
    """Return (start_s, end_s, whole cycles or 0) of the case's window."""
    run = case['run']
    w = run['window']
    if 'last_cycles' in w:
        period = 1.0 / actuation_frequency_hz(scene)
        cycles = int(w['last_cycles'])
        end = float(run['duration_s'])
        return end - cycles * period, end, cycles
    return float(w['from_s']), float(w['to_s']), 0


def _index(t: np.ndarray, time_s: float) -> int:
    return int(np.argmin(np.abs(t - time_s)))


def rest_fluid_mass_kg(model) -> float | None:
    """Fluid mass at the rest shape of a lumped model (None for other models)."""
    if getattr(model, 'name', '') != 'lumped':
        return None
    from pulsejet_sim.models.lumped import kernels as K

    p = model.params
    volume = 4.0 / 3.0 * math.pi * p[K.P_A] * p[K.P_B0] ** 2 - p[K.P_V_SOLID]
    return float(p[K.P_RHO] * volume)


def quantity(trace: Trace, name: str, i0: int, i1: int) -> float | None:
    """One figure's value from the samples i0..i1 of a run (None: not reached in the run)."""
    t, sl = trace.t, slice(i0, i1 + 1)
    if name == 'mean_velocity':
        return float((trace.x[i1] - trace.x[i0]) / (t[i1] - t[i0]))
    if name == 'max_velocity':
        return float(np.max(trace.v[sl]))
    if name == 'max_acceleration':
        return float(np.max(trace.a[sl]))
    if name == 'time_of_max_velocity':
        return float(t[i0 + int(np.argmax(trace.v[sl]))])
    if name == 'volume_range':
        return float(np.max(trace.volume[sl]) - np.min(trace.volume[sl]))
    if name == 'deflation_90_time':
        m_rest = rest_fluid_mass_kg(trace.scene.model)
        if m_rest is None:
            raise ValidationCaseError('deflation_90_time is defined for lumped scenes only')
        m0 = trace.fluid_mass[0]
        out = (m0 - trace.fluid_mass) / (m0 - m_rest)
        hit = np.nonzero(out[sl] >= 0.9)[0]
        if not hit.size:
            return None
        k = i0 + int(hit[0])
        if k == 0:
            return float(t[0])
        f0, f1 = out[k - 1], out[k]
        return float(t[k - 1] + (0.9 - f0) / (f1 - f0) * (t[k] - t[k - 1]))
    raise ValidationCaseError(f'quantity {name!r} unknown; allowed: {", ".join(QUANTITIES)}')


def verdict(fig: dict, predicted: float | None) -> tuple[str, float | None]:
    """('pass' | 'miss', relative error (predicted - measured) / measured)."""
    measured, tol = float(fig['measured']), float(fig['tolerance_relative'])
    if predicted is None or not math.isfinite(predicted):
        return 'miss', None
    err = (predicted - measured) / measured
    kind = fig['comparison']
    if kind == 'value':
        ok = abs(err) <= tol
    elif kind == 'at_least':
        ok = predicted >= (1.0 - tol) * measured
    else:
        ok = predicted <= (1.0 + tol) * measured
    return ('pass' if ok else 'miss'), err


def figures_of(case: dict, trace: Trace) -> tuple[dict, tuple[float, float, int]]:
    start, end, cycles = window_of(case, trace.scene, trace.t[-1])
    i0, i1 = _index(trace.t, start), _index(trace.t, end)
    values = {fig['id']: quantity(trace, fig['quantity'], i0, i1) for fig in case['figures']}
    return values, (float(trace.t[i0]), float(trace.t[i1]), cycles)


# ---------------------------------------------------------------------------------------------
# energy budget


def _ledger_delta(a: dict, b: dict) -> dict:
    return {k: float(b[k] - a.get(k, 0.0)) for k in b if isinstance(b[k], (int, float))}


def energy_budget(case: dict, trace: Trace, figures: dict, window: tuple) -> dict:
    """
    Where the input energy goes over the case's budget interval, and what the measured needs.

    The model's terms are the ledger's changes over the interval (flows booked, stored energies'
    changes). What the measured figures imply: each term scaled to the measured speed with the
    same time history (kinetic energies by the speed ratio squared, drag work by its cube);
    the payload's kinetic energy and the available energy it implies when the case states the
    measured payload energy fraction.
    """
    spec = case.get('budget') or {}
    start, end, cycles = window
    t = trace.t
    i0 = _index(t, start) if spec.get('from', 'window_start') == 'window_start' else 0
    if spec.get('to', 'window_end') == 'peak_speed':
        i1 = i0 + int(np.argmax(trace.v[i0:_index(t, end) + 1]))
    else:
        i1 = _index(t, end)
    led0, led1 = trace.ledgers[i0], trace.ledgers[i1]
    delta = _ledger_delta(led0 if i0 > 0 else {}, led1)
    if i0 > 0:
        delta['in_initial'] = 0.0
        for key in STORED_KEYS:
            if key in led1:
                delta[key] = float(led1[key] - led0[key])
    scale = cycles if (spec.get('per_cycle') and cycles) else 1
    terms = {}
    order = ['in_initial', 'in_actuation_work', *FLOW_KEYS[1:], *STORED_KEYS]
    extra = sorted(
        k
        for k in delta
        if k not in order and (k.startswith('stored_') or k.startswith('created_'))
    )
    for key in order + extra:
        if key in delta:
            terms[key] = delta[key] / scale
    created = [k for k in terms if k.startswith('created_')]
    if created:
        # one row: energy the model's equations create (negative: destroy) beyond the
        # energy-consistent ones; 0 in the consistent couplings
        terms['created_total'] = sum(terms.pop(k) for k in created)
    closure = sum(terms.get(k, 0.0) for k in terms if k.startswith('stored_'))
    closure -= terms.get('in_initial', 0.0) + terms.get('in_actuation_work', 0.0)
    closure += sum(terms.get(k, 0.0) for k in FLOW_KEYS[1:])
    closure -= sum(terms[k] for k in terms if k.startswith('created_'))
    # the speed the implied column scales to: the case's first speed figure
    speed_fig = next(
        (f for f in case['figures'] if f['quantity'] in ('mean_velocity', 'max_velocity')), None
    )
    implied: dict[str, float] = {}
    ratio = None
    if speed_fig is not None and figures.get(speed_fig['id']):
        ratio = float(speed_fig['measured']) / figures[speed_fig['id']]
        for key in ('stored_kinetic_vehicle', 'stored_kinetic_outer_fluid'):
            if key in terms:
                implied[key] = terms[key] * ratio**2
        if 'out_drag' in terms:
            implied['out_drag'] = terms['out_drag'] * ratio**3
    payload = {}
    imp = case.get('implied') or {}
    if 'payload_mass_kg' in imp and speed_fig is not None:
        u_meas = float(speed_fig['measured'])
        u_pred = figures.get(speed_fig['id']) or 0.0
        m = float(imp['payload_mass_kg'])
        payload['payload_kinetic_measured_j'] = 0.5 * m * u_meas**2
        payload['payload_kinetic_predicted_j'] = 0.5 * m * u_pred**2
        if imp.get('payload_energy_fraction'):
            payload['payload_fraction_measured'] = float(imp['payload_energy_fraction'])
            payload['available_energy_implied_j'] = (
                payload['payload_kinetic_measured_j'] / float(imp['payload_energy_fraction'])
            )
        given = terms.get('in_initial', 0.0) + terms.get('in_actuation_work', 0.0)
        if given > 0:
            payload['payload_fraction_predicted'] = payload['payload_kinetic_predicted_j'] / given
    return {
        'interval_s': [float(t[i0]), float(t[i1])],
        'per_cycle': scale > 1,
        'cycles': cycles,
        'speed_ratio_measured_over_predicted': ratio,
        'terms_j': terms,
        'closure_j': closure,
        'implied_j': implied,
        'payload': payload,
    }


# ---------------------------------------------------------------------------------------------
# a case


def case_scene(case: dict, extra: dict | None = None):
    """Return the case's scene with its overrides and then `extra` (a probe's) merged in."""
    overrides = merge(case.get('overrides') or {}, extra or {})
    try:
        return load_scene(case['scene'], overrides or None)
    except SceneError as err:
        raise ValidationCaseError(f'{case["id"]}: {err}') from None


def refinement(case: dict, scene, values: dict, run: dict) -> list[dict]:
    """
    Rerun an unmeshed (lumped) case at step dt/2 and dt/4 (a shell case: shell_case_convergence).

    The series gives the figures and, from the three levels, the observed order
    p = log2(|f1 - f2| / |f2 - f3|) where the differences are above rounding (None otherwise).
    """
    dt = scene.model.dt_s
    series = [('step', [{'simulation': {'dt_s': dt / 2}}, {'simulation': {'dt_s': dt / 4}}])]
    out = []
    for name, levels in series:
        runs = []
        for ov in levels:
            trace = run_trace(
                case_scene(case, ov), float(run['duration_s']), float(run['sample_period_s'])
            )
            figures = figures_of(case, trace)[0]
            runs.append({'overrides': ov, 'fault': trace.fault, 'figures': figures})
        order = {}
        for key, f1 in values.items():
            f2, f3 = (r['figures'].get(key) for r in runs)
            if None in (f1, f2, f3):
                order[key] = None
                continue
            d12, d23 = abs(f1 - f2), abs(f2 - f3)
            tiny = 1e-9 * max(abs(f1), 1e-300)
            order[key] = math.log2(d12 / d23) if d12 > tiny and d23 > tiny else None
        out.append({'series': name, 'levels': runs, 'observed_order': order})
    return out


def _is_meshed(scene) -> bool:
    mesh = scene.data.get('mesh')
    return isinstance(mesh, dict) and 'elements' in mesh


def shell_case_convergence(case: dict, scene, values: dict, run: dict) -> dict:
    """
    Run the convergence study of a shell case (validation/convergence_plan.md).

    Kink-aligned mesh ladder at dt/8 and Newton tolerance 1e-9 with its Richardson estimate,
    checked against a finer mesh; the step ladder and the Newton tolerance's part at the stored
    mesh; the stored mesh doubled (validation_convergence.shell_convergence).
    """
    from pulsejet_sim.studies.validation_convergence import shell_convergence

    def figures_at(overrides: dict):
        trace = run_trace(
            case_scene(case, overrides), float(run['duration_s']), float(run['sample_period_s'])
        )
        return figures_of(case, trace)[0], trace.fault

    return shell_convergence(
        int(scene.data['mesh']['elements']),
        scene.model.dt_s,
        scene.data.get('geometry') or {},
        values,
        figures_at,
    )


def _flag_verdicts(result: dict) -> None:
    """Mark each row whose verdict differs anywhere within the converged estimate +- its error."""
    conv = result['convergence']['figures']
    for row in result['figures']:
        c = conv.get(row['figure']) or {}
        if c.get('converged') is None or row['predicted'] is None:
            row['verdict_within_estimate'] = None
            continue
        spread = abs(row['predicted'] - c['converged']) + c['estimate']
        ends = {verdict(row, c['converged'] + s * spread)[0] for s in (-1.0, 1.0)}
        row['verdict_within_estimate'] = ends == {row['verdict']}


def run_case(case: dict, refine: bool = True, probes: bool = True) -> tuple[dict, Trace]:
    """Run one case: figures with verdicts, steady check, budget, refinement, probes."""
    run = case['run']
    scene = case_scene(case)
    trace = run_trace(scene, float(run['duration_s']), float(run['sample_period_s']))
    values, window = figures_of(case, trace)
    rows = []
    for fig in case['figures']:
        predicted = values[fig['id']]
        result, err = verdict(fig, predicted)
        rows.append(
            {
                'figure': fig['id'],
                'quantity': fig['quantity'],
                'status': fig['status'],
                'measured': float(fig['measured']),
                'unit': fig['unit'],
                'comparison': fig['comparison'],
                'tolerance_relative': float(fig['tolerance_relative']),
                'predicted': predicted,
                'error_relative': err,
                'verdict': result,
            }
        )
    out = {
        'id': case['id'],
        'title': case['title'],
        'scene': case['scene'],
        'robot': case.get('robot', ''),
        'protocol': run['protocol'],
        'window_s': [window[0], window[1]],
        'dt_s': trace.dt_s,
        'fault': trace.fault,
        'figures': rows,
        'budget': energy_budget(case, trace, values, window),
    }
    check = run.get('steady_check')
    if check and window[2]:
        n = int(check['previous_cycles'])
        period = (window[1] - window[0]) / window[2]
        i0, i1 = _index(trace.t, window[0] - n * period), _index(trace.t, window[0])
        before = quantity(trace, 'mean_velocity', i0, i1)
        j0, j1 = _index(trace.t, window[0]), _index(trace.t, window[1])
        now = quantity(trace, 'mean_velocity', j0, j1)
        out['steady_check'] = {
            'previous_window_s': [float(trace.t[i0]), float(trace.t[i1])],
            'mean_velocity_previous': before,
            'mean_velocity_window': now,
            'change_relative': (now - before) / now if now else None,
        }
    if refine and _is_meshed(scene):
        out['convergence'] = shell_case_convergence(case, scene, values, run)
        _flag_verdicts(out)
    elif refine:
        out['refinement'] = refinement(case, scene, values, run)
    out['probes'] = []
    if probes:
        for probe in case.get('probes') or []:
            ptrace = run_trace(
                case_scene(case, probe['overrides']),
                float(run['duration_s']),
                float(run['sample_period_s']),
            )
            pvalues, pwindow = figures_of(case, ptrace)
            out['probes'].append(
                {
                    'id': probe['id'],
                    'overrides': probe['overrides'],
                    'why': ' '.join(str(probe.get('why', '')).split()),
                    'fault': ptrace.fault,
                    'figures': pvalues,
                    'budget': energy_budget(case, ptrace, pvalues, pwindow),
                }
            )
    return out, trace


# ---------------------------------------------------------------------------------------------
# report


def _g(value, spec='.4g') -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return 'not reached'
    return format(value, spec)


def _pct(value) -> str:
    return 'n/a' if value is None else f'{100.0 * value:+.1f} %'


def _bound(row: dict) -> str:
    sign = {'value': '', 'at_least': '>= ', 'at_most': '<= '}[row['comparison']]
    return f'{sign}{_g(row["measured"])}'


def figure_rows(result: dict) -> list[str]:
    """Return the table rows of one case (the stored-row test compares them as text)."""
    rows = []
    for r in result['figures']:
        rows.append(
            f'| {result["id"]} | {r["figure"]} | {r["status"]} | {_bound(r)} {r["unit"]} | '
            f'{_g(r["predicted"])} | {_pct(r["error_relative"])} | '
            f'{100 * r["tolerance_relative"]:.0f} % | **{r["verdict"]}** |'
        )
    return rows


def budget_table(result: dict) -> list[str]:
    b = result['budget']
    unit = 'J per cycle' if b['per_cycle'] else 'J'
    terms, implied = b['terms_j'], b['implied_j']
    given = terms.get('in_initial', 0.0) + terms.get('in_actuation_work', 0.0)
    lines = [
        f'Interval {b["interval_s"][0]:.3g}-{b["interval_s"][1]:.3g} s'
        + (f' ({b["cycles"]} cycles, per cycle)' if b['per_cycle'] else '')
        + f'; closure {b["closure_j"]:.2e} {unit}.',
        '',
        f'| term | model [{unit}] | share of input | at the measured speed [{unit}] |',
        '|---|---|---|---|',
    ]
    for key, value in terms.items():
        share = f'{100 * value / given:.1f} %' if given > 0 else ''
        label = _stored_label(key, b['interval_s'][0])
        scaled = _g(implied[key], '.4g') if key in implied else ''
        lines.append(f'| {label} | {value:.4g} | {share} | {scaled} |')
    if implied and given > 0:
        extra = sum(implied[k] - terms[k] for k in implied)
        lines.append(
            '| **extra input the measured speed needs** (same history; sum of the scaled rows '
            f"minus the model's) | | | **{extra:.4g}** ({100 * extra / given:.0f} % of the "
            "model's input) |"
        )
    pay = b.get('payload') or {}
    if pay:
        lines.append('')
        lines.append(
            'Kinetic energy of the measured payload: at the measured speed '
            f'{_g(pay["payload_kinetic_measured_j"])} J, at the predicted speed '
            f'{_g(pay["payload_kinetic_predicted_j"])} J'
            + (
                f' ({100 * pay["payload_fraction_predicted"]:.0f} % of the model\'s input)'
                if 'payload_fraction_predicted' in pay
                else ''
            )
            + (
                f'; the measured payload fraction {100 * pay["payload_fraction_measured"]:.0f} % '
                f'implies {_g(pay["available_energy_implied_j"])} J available, against the '
                f"model's {given:.4g} J input."
                if 'available_energy_implied_j' in pay
                else '.'
            )
        )
    return lines


def write_plot(result: dict, trace: Trace, case: dict, path: Path) -> Path:
    """Plot the predicted velocity, acceleration and volume with the measured figures marked."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 8), constrained_layout=True)
    axes = fig.subplots(3, 1, sharex=True)
    t = trace.t
    w0, w1 = result['window_s']
    axes[0].plot(t, trace.v, lw=1.0, label='predicted velocity')
    axes[1].plot(t, trace.a, lw=1.0, color='C1', label='predicted acceleration')
    axes[2].plot(t, trace.volume * 1e6, lw=1.0, color='C2', label='predicted volume')
    for ax in axes:
        ax.axvspan(w0, w1, color='0.5', alpha=0.12, lw=0)
        ax.grid(True, alpha=0.3)
    panel = {
        'mean_velocity': 0,
        'max_velocity': 0,
        'time_of_max_velocity': 0,
        'max_acceleration': 1,
        'volume_range': 2,
        'deflation_90_time': 2,
    }
    for k, row in enumerate(result['figures']):
        ax = axes[panel[row['quantity']]]
        color = f'C{3 + k}'
        m, tol = row['measured'], row['tolerance_relative']
        name = row['figure']
        label = f'measured {name} ({_bound(row)} {row["unit"]}; {row["verdict"]})'
        if row['quantity'] in ('time_of_max_velocity', 'deflation_90_time'):
            ax.axvline(m, color=color, ls='--', label=label)
            if row['predicted'] is not None:
                ax.axvline(row['predicted'], color=color, ls=':', label=f'predicted {name}')
        elif row['quantity'] == 'volume_range':
            ax.annotate(
                f'{label}; predicted {_g(row["predicted"] * 1e6)} ml', (0.01, 0.05),
                xycoords='axes fraction', fontsize=8,
            )
        else:
            # the band of predicted values that pass (open-ended for a bound)
            top = max(ax.get_ylim()[1], m * (1 + tol))
            lo = m * (1 - tol) if row['comparison'] != 'at_most' else ax.get_ylim()[0]
            hi = m * (1 + tol) if row['comparison'] == 'value' else top
            if row['comparison'] == 'at_most':
                hi = m * (1 + tol)
            ax.axhline(m, color=color, ls='--', label=label)
            ax.fill_between([w0, w1], [lo] * 2, [hi] * 2, color=color, alpha=0.12)
            if row['predicted'] is not None:
                ax.axhline(row['predicted'], color=color, ls=':', label=f'predicted {name}')
        ax.legend(fontsize=7, loc='upper right')
    axes[0].set_ylabel('velocity [m/s]')
    axes[1].set_ylabel('acceleration [m/s^2]')
    axes[2].set_ylabel('volume [ml]')
    axes[2].set_xlabel("simulation time [s] (shaded: the figures' window)")
    axes[0].set_title(f'{result["id"]}: {result["title"]}', fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    return path


def _stored_label(key: str, interval_start_s: float) -> str:
    label = LABELS.get(key, key.replace('_', ' '))
    if key.startswith('stored_'):
        label += ' (change)' if interval_start_s > 0 else ' (at the end)'
    return label


def _probe_section(result: dict) -> list[str]:
    figs = [r['figure'] for r in result['figures']]
    lines = [
        '',
        '### Numerical experiments (not predictions)',
        '',
        '| probe | change | ' + ' | '.join(figs) + ' | why |',
        '|---|---|' + '---|' * len(figs) + '---|',
    ]
    for p in result['probes']:
        cells = ' | '.join(_g(p['figures'].get(name)) for name in figs)
        fault = f' FAULT: {p["fault"]}' if p['fault'] else ''
        change = json.dumps(p['overrides'])
        lines.append(f'| {p["id"]} | `{change}` | {cells} | {p["why"]} |{fault}')
    budget = result['budget']
    unit = 'J per cycle' if budget['per_cycle'] else 'J'
    lines += [
        '',
        f'Probe budgets (same interval, {unit}):',
        '',
        '| term | model | ' + ' | '.join(p['id'] for p in result['probes']) + ' |',
        '|---|---|' + '---|' * len(result['probes']),
    ]
    for key, value in budget['terms_j'].items():
        cells = ' | '.join(_g(p['budget']['terms_j'].get(key), '.4g') for p in result['probes'])
        label = _stored_label(key, budget['interval_s'][0])
        lines.append(f'| {label} | {value:.4g} | {cells} |')
    return lines


def _case_section(result: dict) -> list[str]:
    w0, w1 = result['window_s']
    fault = f'; FAULT: {result["fault"]}' if result['fault'] else ''
    lines = [
        f'## {result["id"]}: {result["title"]}',
        '',
        f'Scene `{result["scene"]}`, {result["protocol"]}, figures over {w0:.4g}-{w1:.4g} s, '
        f'step {result["dt_s"]:g} s{fault}.',
    ]
    sc = result.get('steady_check')
    if sc:
        lines.append(
            f'Steady check: mean speed {sc["mean_velocity_window"]:.4g} m/s over the window, '
            f'{sc["mean_velocity_previous"]:.4g} m/s over the cycles before '
            f'({_pct(sc["change_relative"])}).'
        )
    for ser in result.get('refinement', []):
        parts = []
        for r in result['figures']:
            name = r['figure']
            vals = [r['predicted']] + [lv['figures'].get(name) for lv in ser['levels']]
            p = ser['observed_order'].get(name)
            rel = (
                _pct((vals[0] - vals[-1]) / vals[-1])
                if None not in vals and vals[-1]
                else 'n/a'
            )
            order = f', observed order {p:.2f}' if p is not None else ''
            if p is None and None not in vals and vals[-1]:
                spread = max(abs(v - vals[-1]) for v in vals) / abs(vals[-1])
                if spread <= 1e-9:
                    # the rule of refinement(): no order is read from differences at rounding
                    order = f', differences {spread:.0e} relative: at rounding, no order'
            levels = ' / '.join(_g(v) for v in vals)
            parts.append(f'{name} {levels} (stored vs finest {rel}{order})')
        what = {'step': 'step dt, dt/2, dt/4', 'elements': 'elements n, 2n, 4n'}[ser['series']]
        lines.append(f'Refinement ({what}): ' + '; '.join(parts) + '.')
    if result.get('convergence'):
        lines += convergence_lines(result)
    lines += ['', f'![{result["id"]}]({result["id"]}.png)', '', '### Energy budget', '']
    lines += budget_table(result)
    if result['probes']:
        lines += _probe_section(result)
    lines.append('')
    return lines


def _order(p, why: str = '') -> str:
    return f'{p:.2f}' if p is not None else f'none ({why})'


def _rel(value, spec: str = '+.2g') -> str:
    return 'n/a' if value is None else f'{100.0 * value:{spec}} %'


def convergence_lines(result: dict) -> list[str]:
    """Render a shell case's convergence study (validation/convergence_plan.md) as a table."""
    conv = result['convergence']
    ladder = [r['elements'] for r in conv['mesh_ladder']]
    steps = [r['dt_s'] for r in conv['step_ladder']]
    doubled = [r['elements'] for r in conv['doubled_stored_mesh']]
    places = ', '.join(
        f'{n}: ' + '/'.join(f'{x:.2f}' for x in v)
        for n, v in conv['kink_place_in_element'].items()
    )
    faults = [
        f'{r["elements"]} el. {r["dt_s"]:g} s: {r["fault"]}'
        for key in ('mesh_ladder', 'step_ladder', 'doubled_stored_mesh')
        for r in conv[key]
        if r['fault']
    ]
    lines = [
        '',
        '### Convergence',
        '',
        f'Mesh ladder {"/".join(map(str, ladder[:3]))} elements (a node on the cap/cylinder kink; '
        f"the kink's place inside its element, by mesh: {places}) at step "
        f'{conv["ladder_dt_s"]:g} s and Newton tolerance {conv["newton_tolerance"]:g}; '
        f'checked against {ladder[3]} elements. Converged = Richardson estimate with the '
        f'observed order when that order is within 0.5 of 2, error estimate = 1.25 |f{ladder[2]} '
        f"- converged| + the step's error at {conv['ladder_dt_s']:g} s ({ladder[1]} elements, "
        f'|f({2 * conv["ladder_dt_s"]:g} s) - f({conv["ladder_dt_s"]:g} s)| / 3); when the '
        f'order is not, converged = the {ladder[3]}-element run and error estimate = the larger '
        f'of |f{ladder[1]} - f{ladder[2]}| and |f{ladder[2]} - f{ladder[3]}| (the error left at '
        f'{ladder[3]} elements if it is first order) + the same step error. The stored '
        "error is split into the Newton tolerance's part (the stored run against the same mesh "
        f"and step at {conv['newton_tolerance']:g}), the step's part (step ladder "
        f'{", ".join(f"{d:g}" for d in steps)} s at the stored mesh) and the mesh'
        "'s part (the "
        'rest). Last column: the stored mesh doubled '
        f'({"/".join(map(str, doubled))} elements at {conv["ladder_dt_s"]:g} s), whose kink falls '
        'at a different place in its element at each level.'
        + (' FAULT: ' + '; '.join(faults) if faults else ''),
        '',
        f'| figure | stored | converged +- estimate | how | stored error (tolerance / step / '
        f'mesh part) | ladder {"/".join(map(str, ladder[:3]))}: order | check {ladder[3]} '
        f'(order {"/".join(map(str, ladder[1:]))}) | step order at {doubled[0]} el. | '
        f'{"/".join(map(str, doubled))}: order |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    for row in result['figures']:
        c = conv['figures'].get(row['figure']) or {}
        if c.get('converged') is None:
            lines.append(f'| {row["figure"]} | {_g(row["predicted"])} | {c.get("how", "n/a")} |')
            continue
        ok = {True: 'within', False: '**outside**', None: 'not independent'}[c['check_ok']]
        flip = row.get('verdict_within_estimate')
        verdict_note = '' if flip in (True, None) else ' (**verdict changes within it**)'
        lines.append(
            f'| {row["figure"]} | {_g(c.get("stored"), ".6g")} | '
            f'{_g(c["converged"], ".6g")} +- {_rel(c["estimate_rel"], ".2g")}{verdict_note} | '
            f'{c["how"]} | {_rel(c.get("stored_error_rel"))} ({_rel(c.get("tolerance_part_rel"))}'
            f' / {_rel(c.get("step_part_rel"))} / {_rel(c.get("mesh_part_rel"))}) | '
            f'{" / ".join(_g(v, ".6g") for v in c["ladder"])}: '
            f'{_order(c["order"], c["order_why"])} | '
            f'{_g(c["check"], ".6g")}: {_rel(c.get("check_rel"))}, {ok} '
            f'(order {_order(c["order_fine"], c["order_fine_why"])}) | '
            f'{_order(c.get("step_order"), c.get("step_order_why", ""))}, '
            f'{_order(c.get("step_order_fine"), c.get("step_order_fine_why", ""))} | '
            f'{" / ".join(_g(v, ".6g") for v in c["doubled"])}: '
            f'{_order(c["doubled_order"], c["doubled_order_why"])} |'
        )
    return lines


def write_report(results: dict, out_dir: Path, meta: dict) -> Path:
    """Write report.md: the predicted-against-measured table, then each case's section."""
    lines = [
        '# Validation report',
        '',
        f'Written by `{COMMAND}` ({meta["written"]}, {meta["machine"]}, {meta["commit"]}); '
        "cases in `validation/cases/` (each figure's source, reading and tolerance); "
        '[README](README.md) explains the cases and the verdicts. Regenerate with '
        f'`{COMMAND}`.',
        '',
        '## Predicted against measured',
        '',
        'Status: `predicted` = nothing fitted to it; `fitted` = a scene value was chosen to '
        'reproduce it; `fitted_upstream` = a value the scene takes from its source was fitted '
        'there to the same experiment. Error = (predicted - measured) / measured.',
        '',
        '| case | figure | status | measured | predicted | error | tolerance | verdict |',
        '|---|---|---|---|---|---|---|---|',
    ]
    for result in results.values():
        lines += figure_rows(result)
    lines.append('')
    for result in results.values():
        lines += _case_section(result)
    path = out_dir / 'report.md'
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines) + '\n')
    return path


def run_posthoc(path: Path, cases_dir: Path, log=print) -> list[dict]:
    """Run the post-hoc numerical experiments (chosen after the results; not predictions)."""
    try:
        items = read_yaml_file(path, f'post-hoc experiments {str(path)!r}')
    except YAMLInputError as err:
        raise ValidationCaseError(str(err)) from None
    if not isinstance(items, list):
        raise ValidationCaseError(f'{str(path)!r}: not a list of experiments')
    out = []
    for i, item in enumerate(items):
        where = f'{path.name}[{i}]'
        case = load_case(case_paths([_need(item, 'case', where, str)], cases_dir)[0])
        overrides = _need(item, 'overrides', where, dict)
        log(f'post-hoc {case["id"]}/{_need(item, "id", where, str)} ...')
        run = case['run']
        trace = run_trace(
            case_scene(case, overrides), float(run['duration_s']), float(run['sample_period_s'])
        )
        values, window = figures_of(case, trace)
        out.append(
            _clean(
                {
                    'case': case['id'],
                    'id': item['id'],
                    'overrides': overrides,
                    'why': ' '.join(str(item.get('why', '')).split()),
                    'fault': trace.fault,
                    'figures': values,
                    'measured': {f['id']: f['measured'] for f in case['figures']},
                    'status': {f['id']: f['status'] for f in case['figures']},
                    'budget': energy_budget(case, trace, values, window),
                }
            )
        )
    return out


def write_posthoc(items: list[dict], out_dir: Path) -> Path:
    """Write posthoc.md: each experiment's figures and where the energy went."""
    lines = [
        '# Post-hoc numerical experiments',
        '',
        'Chosen after the first results of the validation cases (validation/posthoc.yaml) to '
        'locate what explains a miss; not predictions, no case changed. Written by '
        f'`{COMMAND}`.',
        '',
    ]
    for item in items:
        terms = item['budget']['terms_j']
        given = terms.get('in_initial', 0.0) + terms.get('in_actuation_work', 0.0)
        status = item.get('status', {})
        figs = ', '.join(
            f'{k} {_g(v)} (measured {_g(item["measured"][k])}'
            + (f', {status[k]}' if status.get(k, 'predicted') != 'predicted' else '')
            + ')'
            for k, v in item['figures'].items()
        )
        shares = ', '.join(
            f'{LABELS.get(k, k).split(" (")[0]} {100 * v / given:.0f} %'
            for k, v in terms.items()
            if given > 0 and abs(v) > 1e-3 * given and not k.startswith('in_')
        )
        lines += [
            f'## {item["case"]} / {item["id"]}',
            '',
            f'Change `{json.dumps(item["overrides"])}`: {item["why"]}.',
            '',
            f'Figures: {figs}.',
            '',
            f"Where the input ({given:.4g} J) went by the budget's end: {shares}.",
            '',
        ]
    path = out_dir / 'posthoc.md'
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines))
    return path


def _meta() -> dict:
    import subprocess

    try:
        commit = subprocess.run(
            ['git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD'],
            capture_output=True, text=True, check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = 'unknown commit'
    return {
        'written': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
        'machine': f'{platform.machine()} {platform.system()}, Python {platform.python_version()}',
        'commit': f'commit {commit}',
    }


def _clean(value):
    """JSON-safe copy (numpy scalars to floats)."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def validate(
    names: Sequence[str] = (),
    out_dir: Path = OUT_DIR,
    cases_dir: Path = CASES_DIR,
    plots: bool = True,
    refine: bool = True,
    probes: bool = True,
    log=print,
) -> dict:
    """Run the named cases (all by default), store their rows and rewrite the report."""
    out_dir = Path(out_dir)
    stored_path = out_dir / 'results.json'
    stored = json.loads(stored_path.read_text()) if stored_path.is_file() else {}
    results = dict(stored.get('cases', {}))
    for path in case_paths(names, cases_dir):
        case = load_case(path)
        log(f'{case["id"]}: running {case["scene"]} ...')
        result, trace = run_case(case, refine=refine, probes=probes)
        results[case['id']] = _clean(result)
        if plots:
            write_plot(result, trace, case, out_dir / f'{case["id"]}.png')
        for row in figure_rows(result):
            log(row)
    posthoc = stored.get('posthoc', [])
    if not names and Path(cases_dir) == CASES_DIR and POSTHOC_FILE.is_file():
        posthoc = run_posthoc(POSTHOC_FILE, cases_dir, log)
        write_posthoc(posthoc, out_dir)
    order = [p.stem for p in case_paths((), cases_dir)]
    results = {k: results[k] for k in order if k in results}
    meta = _meta()
    out_dir.mkdir(parents=True, exist_ok=True)
    stored_path.write_text(
        json.dumps({'meta': meta, 'cases': results, 'posthoc': posthoc}, indent=1) + '\n'
    )
    write_report(results, out_dir, meta)
    return results


def main_validate(argv: Sequence[str] | None = None) -> int:
    """`pulsejet validate [CASE...]`: run validation cases and write docs/validation/."""
    parser = argparse.ArgumentParser(
        prog=COMMAND,
        description='Run validation cases (validation/cases/*.yaml) and write the report '
        '(docs/validation/report.md, results.json, one PNG per case).',
    )
    parser.add_argument('cases', nargs='*', help='case ids or files (default: all)')
    parser.add_argument('--out-dir', default=str(OUT_DIR), help='where the report is written')
    parser.add_argument('--no-plots', action='store_true', help='do not write the PNGs')
    parser.add_argument('--no-refine', action='store_true', help='skip the refinement reruns')
    parser.add_argument('--no-probes', action='store_true', help='skip the numerical experiments')
    args = parser.parse_args(argv)
    try:
        validate(
            args.cases,
            Path(args.out_dir),
            plots=not args.no_plots,
            refine=not args.no_refine,
            probes=not args.no_probes,
        )
    except ValidationCaseError as err:
        print(f'{COMMAND}: {err}', file=sys.stderr)
        return 2
    print(f'report: {Path(args.out_dir) / "report.md"}')
    return 0
