"""
`pulsejet optimize`: search scene parameters within bounds with differential evolution.

The population is evaluated on an executor (local processes, or Dask: `--dask-workers N`,
`--scheduler tcp://HOST:PORT`, see `sweep.open_executor`).

Every evaluation is one real offline run (`sweep.run_one` of a `sweep.RunSpec`, no ROS); a
generation is submitted at once and collected in its order, so the search, the history and the
best design do not depend on the executor or on the order in which runs finish.

Optimisation file (YAML, `config/optimize/`)::

    name: paper000_external                # default: the file's stem
    # the base design: either a study of a sweep file (its base scene, overrides and replace) ...
    sweep: paper000_study
    study: external
    fixed: {coupling: consistent}          # labels of the study's axes held fixed; other axes not
                                           # searched take their first label (a searched parameter
                                           # must then overwrite what that label sets)
    overrides: {actuation: {pulse: half_cosine}}   # optional: on top of the study's overrides
    # ... or a scene:  scene: escape / overrides: {...} / replace: [...]
    duration_s: 4.0                        # default: the sweep's (or 5 s)
    objective: {metric: peak_speed_m_s, sense: max}       # a sweep metric, one of sweep.METRICS
    parameters:
      material.youngs_modulus_pa: {low: 2.0e4, high: 8.0e4}   # a dotted scene key (a number),
                                                              # linear
      period_s: {low: 0.53, high: 0.79}                       # no dot: a variable of `derived`
                                                              # only
      mantle: {axis: mantle}                                  # one label of the study's axis
      actuation.distribution: {choices: [rising, falling]}    # one of these values of a scene key
    derived:                               # dotted scene key -> expression of the parameters
      actuation.frequency_hz: 1 / period_s
    options: {max_evals: 36, population: 12, seed: 1, mutation: [0.5, 1.0], crossover: 0.9}
    compare:                               # optional: a stored grid to beat
      csv: ../../benchmarks/results/paper000_study/study.csv   # relative to this file
      where: {study: external, coupling: consistent}
      rerun: true                          # also rerun the grid's best with today's code

Search: differential evolution, best/1/bin with dither (F drawn per generation from `mutation`),
crossover rate `crossover`, an initial Latin hypercube of `population` designs (seeded), every
trial clipped to the bounds (a design on a bound stays reachable), greedy one-to-one selection.
The number of runs never exceeds `max_evals` (the last generation is cut short if needed).
A run that faults or has no metric never wins. Parameters move in [0, 1] between their bounds
(linear, or `scale: log`); a choice parameter takes label floor(u * n).

Outputs (`--out DIR`, default runs/optimize/<name>/): `best_scene.yaml` (the best design's full
scene, loadable by every tool and node), `history.csv` (one row per run: parameters, metrics, best
so far; deterministic columns only), `convergence.png`, `optimize_results.yaml` (best values, the
comparison with the grid).
"""

from __future__ import annotations

import argparse
import ast
import csv
from dataclasses import dataclass, field
import math
from pathlib import Path
import sys
import time
from typing import Any, Callable, Sequence

import numpy as np
from pulsejet_sim.core.schema import Number
from pulsejet_sim.studies.fit import dotted_overrides, get_dotted, Parameter
from pulsejet_sim.studies.sweep import (
    executor_label,
    load_sweep,
    merge,
    METRICS,
    open_executor,
    run_one,
    RunRow,
    RunSpec,
    SweepError,
)
import yaml

TOP_KEYS = (
    'name',
    'description',
    'sweep',
    'study',
    'fixed',
    'scene',
    'overrides',
    'replace',
    'duration_s',
    'objective',
    'parameters',
    'derived',
    'options',
    'compare',
)
OPTION_DEFAULTS = {
    'max_evals': 36,
    'population': 12,
    'seed': 1,
    'mutation': [0.5, 1.0],
    'crossover': 0.9,
}
SENSES = ('max', 'min')


class OptimizeError(ValueError):
    """An optimisation file that cannot be run (names the key, the value and what is allowed)."""


# ---------------------------------------------------------------- differential evolution


@dataclass
class Evaluation:
    index: int  # 0-based run number
    generation: int  # 0: the initial population
    unit: np.ndarray  # the design in [0, 1]^d
    cost: float  # minimised; inf for a run that failed


def differential_evolution(
    evaluate: Callable[[list[np.ndarray]], list[float]],
    dims: int,
    max_evals: int,
    population: int = 12,
    seed: int = 1,
    mutation: Sequence[float] = (0.5, 1.0),
    crossover: float = 0.9,
) -> list[Evaluation]:
    """
    Minimise over the unit cube with at most max_evals calls' worth of designs.

    `evaluate` gets a whole generation (a list of designs) at once and returns their costs in the
    same order. Returns every evaluation in order (the history).
    """
    from scipy.stats import qmc

    if dims < 1 or max_evals < 1 or population < 4:
        raise OptimizeError(
            f'differential evolution: dims={dims}, max_evals={max_evals}, '
            f'population={population}; '
            'allowed: dims >= 1, max_evals >= 1, population >= 4'
        )
    rng = np.random.default_rng(seed)
    n0 = min(population, max_evals)
    pop = qmc.LatinHypercube(d=dims, seed=rng).random(population)[:n0]
    history: list[Evaluation] = []

    def run(designs: list[np.ndarray], generation: int) -> list[float]:
        costs = [
            float(c) if c is not None and math.isfinite(c) else math.inf for c in evaluate(designs)
        ]
        for u, c in zip(designs, costs):
            history.append(Evaluation(len(history), generation, np.array(u, dtype=float), c))
        return costs

    costs = np.array(run(list(pop), 0))
    generation = 0
    while len(history) < max_evals:
        generation += 1
        n = len(pop)
        best = pop[int(np.argmin(costs))]
        f = rng.uniform(*mutation) if len(mutation) == 2 else float(mutation[0])
        trials = []
        for i in range(n):
            r1, r2 = rng.choice([j for j in range(n) if j != i], 2, replace=False)
            mutant = np.clip(best + f * (pop[r1] - pop[r2]), 0.0, 1.0)
            cross = rng.random(dims) < crossover
            cross[rng.integers(dims)] = True  # at least one coordinate from the mutant
            trials.append(np.where(cross, mutant, pop[i]))
        order = list(range(n))[: max_evals - len(history)]
        trial_costs = run([trials[i] for i in order], generation)
        for i, c in zip(order, trial_costs):
            if c <= costs[i]:
                pop[i], costs[i] = trials[i], c
    return history


# ---------------------------------------------------------------- optimisation file


@dataclass
class Choice:
    name: str
    options: list[Any]  # values (a scene key) or labels (an axis)
    axis: bool = False

    def from_unit(self, u: float) -> Any:
        return self.options[
            min(int(math.floor(min(max(u, 0.0), 1.0) * len(self.options))), len(self.options) - 1)
        ]


@dataclass
class OptimizeSpec:
    path: Path
    name: str
    objective: str
    sense: str
    duration_s: float
    parameters: list[Parameter | Choice]
    derived: dict[str, str]
    options: dict
    base_runs: dict[tuple, RunSpec]  # axis choices -> the base run of that variant
    axis_choices: list[str] = field(default_factory=list)
    defaults: dict[str, str] = field(default_factory=dict)  # axis -> label (fixed or first)
    compare: dict | None = None
    sweep_runs: list[RunSpec] = field(default_factory=list)

    def values(self, unit: np.ndarray) -> dict[str, Any]:
        return {
            p.key if isinstance(p, Parameter) else p.name: p.from_unit(u)
            for p, u in zip(self.parameters, unit)
        }

    def run_spec(self, values: dict[str, Any], label: str) -> RunSpec:
        key = tuple(values[a] for a in self.axis_choices)
        base = self.base_runs[key]
        scene_values = {k: v for k, v in values.items() if '.' in k}
        scene_values.update({k: _evaluate(expr, values) for k, expr in self.derived.items()})
        labels = tuple((a, str(values[a])) for a in self.axis_choices) + (('eval', label),)
        return RunSpec(
            study=self.name,
            labels=labels,
            scene=base.scene,
            overrides=merge(dict(base.overrides), dotted_overrides(scene_values)),
            duration_s=self.duration_s,
            replace=base.replace,
        )

    def cost(self, row: RunRow) -> float:
        value = row.metrics.get(self.objective)
        if row.fault or value is None or not math.isfinite(value):
            return math.inf
        return -value if self.sense == 'max' else value


_ALLOWED_NODES = (
    ast.Expression,
    ast.BinOp,
    ast.UnaryOp,
    ast.Constant,
    ast.Name,
    ast.Load,
    ast.Add,
    ast.Sub,
    ast.Mult,
    ast.Div,
    ast.Pow,
    ast.USub,
    ast.UAdd,
)


def _check_expression(expr: str, names: set[str], where: str) -> None:
    try:
        tree = ast.parse(str(expr), mode='eval')
    except SyntaxError as err:
        raise OptimizeError(
            f'{where}: {expr!r} is not an expression ({err.msg}); allowed: numbers, parameter '
            'names, + - * / **'
        ) from None
    for node in ast.walk(tree):
        if not isinstance(node, _ALLOWED_NODES):
            raise OptimizeError(
                f'{where}: {expr!r}: {type(node).__name__} not allowed; allowed: numbers, '
                'parameter names, + - * / **'
            )
        if isinstance(node, ast.Name) and node.id not in names:
            raise OptimizeError(
                f'{where}: {expr!r}: unknown name {node.id!r}; allowed: {", ".join(sorted(names))}'
            )


def _evaluate(expr: str, values: dict[str, Any]) -> float:
    names = {k: v for k, v in values.items() if isinstance(v, (int, float))}
    return float(
        eval(
            compile(ast.parse(str(expr), mode='eval'), '<derived>', 'eval'),
            {'__builtins__': {}},
            names,
        )
    )


def _number(value: Any, where: str, allowed: str, positive: bool = False) -> float:
    """Return an optimisation file's number by the one schema rule, or OptimizeError."""
    rule = Number(None, 0.0, low_open=True) if positive else Number(None)
    return rule.accept(value, where, error=OptimizeError, allowed=allowed)


def load_optimize(path: str | Path) -> OptimizeSpec:
    """
    Read and validate an optimisation file (a path, or a name under config/optimize/).

    Each section is checked in file order by its own reader below, then the spec is built and
    its base scenes and corner designs are loaded once, so a bad key or range is refused before
    any run. Raises OptimizeError naming the file, the key and what is allowed.
    """
    p, data = _read_optimize_file(path)
    name = str(data.get('name', p.stem))
    metric, sense = _objective(p, data)
    options = _options(p, data)
    if 'sweep' in data:
        runs, axes, duration, sweep_runs = _study_runs(p, data)
    else:
        runs, axes, sweep_runs = _scene_runs(p, data, name), {}, []
        duration = data.get('duration_s', 5.0)
    duration = _number(duration, f'{p}: duration_s', 'a positive number of seconds', positive=True)
    fixed = _fixed_labels(p, data, axes)
    parameters = _parameters(p, data, axes, fixed)
    derived = _derived(p, data, parameters)
    axis_choices = [q.name for q in parameters if isinstance(q, Choice) and q.axis]
    defaults = {a: fixed.get(a, labels[0]) for a, labels in axes.items()}
    spec = OptimizeSpec(
        path=p,
        name=name,
        objective=metric,
        sense=sense,
        duration_s=duration,
        parameters=parameters,
        derived=derived,
        options=options,
        base_runs=_base_runs(p, runs, axes, axis_choices, defaults),
        axis_choices=axis_choices,
        defaults=defaults,
        sweep_runs=sweep_runs,
    )
    _check_scene_keys(spec)
    _check_corner_designs(spec)
    spec.compare = _compare(p, data)
    return spec


def _read_optimize_file(path: str | Path) -> tuple[Path, dict]:
    """Return (resolved path, top-level mapping) of an optimisation file with only known keys."""
    from pulsejet_sim.scene.paths import read_config_file

    p, data = read_config_file(path, 'optimize', 'optimisation file', OptimizeError)
    if not isinstance(data, dict):
        raise OptimizeError(
            f'{p}: top level must be a mapping; allowed keys: {", ".join(TOP_KEYS)}'
        )
    for key in data:
        if key not in TOP_KEYS:
            raise OptimizeError(f'{p}: {key}: unknown key; allowed: {", ".join(TOP_KEYS)}')
    return p, data


def _objective(p: Path, data: dict) -> tuple[str, str]:
    """Return (metric, sense) of `objective`: a sweep metric (METRICS) to maximise or minimise."""
    objective = data.get('objective') or {}
    metric, sense = objective.get('metric', 'peak_speed_m_s'), objective.get('sense', 'max')
    if metric not in METRICS:
        raise OptimizeError(
            f'{p}: objective.metric: {metric!r} is not known; allowed: one of {", ".join(METRICS)}'
        )
    if sense not in SENSES:
        raise OptimizeError(f'{p}: objective.sense: {sense!r}; allowed: max or min')
    return metric, sense


def _options(p: Path, data: dict) -> dict:
    """Return the search options (OPTION_DEFAULTS filled in); the counts must be integers."""
    options = dict(OPTION_DEFAULTS)
    for key, value in (data.get('options') or {}).items():
        if key not in OPTION_DEFAULTS:
            raise OptimizeError(
                f'{p}: options.{key}: unknown key; allowed: {", ".join(OPTION_DEFAULTS)}'
            )
        options[key] = value
    # differential evolution needs four designs to mutate one from three others
    smallest = {'max_evals': 1, 'population': 4, 'seed': 0}
    for key, least in smallest.items():
        if (
            isinstance(options[key], bool)
            or not isinstance(options[key], int)
            or options[key] < least
        ):
            raise OptimizeError(
                f'{p}: options.{key}: {options[key]!r} rejected; allowed: an integer >= {least}'
            )
    return options


def _study_runs(p: Path, data: dict) -> tuple[list[RunSpec], dict[str, list[str]], Any, list]:
    """
    Return the base runs of `study` in the `sweep` file, its axes, the raw duration, all runs.

    Axes map each axis to its labels in the sweep's order; `overrides` go on top of the study's
    own (what the study's base must change).
    """
    sweep_path = data['sweep']
    if not Path(str(sweep_path)).is_file() and (p.parent / str(sweep_path)).is_file():
        sweep_path = p.parent / str(sweep_path)
    try:
        meta, sweep_runs = load_sweep(sweep_path)
    except (SweepError, yaml.YAMLError) as err:
        raise OptimizeError(f'{p}: sweep: {err}') from None
    study = data.get('study')
    extra = data.get('overrides') or {}
    if not isinstance(extra, dict):
        raise OptimizeError(f'{p}: overrides: {extra!r} rejected; allowed: a mapping')
    runs = [
        RunSpec(r.study, r.labels, r.scene, merge(r.overrides, extra), r.duration_s, r.replace)
        for r in sweep_runs
        if r.study == study
    ]
    if not runs:
        raise OptimizeError(
            f'{p}: study: {study!r} is not a study of {meta["path"]}; allowed: one of '
            f'{", ".join(dict.fromkeys(r.study for r in sweep_runs))}'
        )
    axes: dict[str, list[str]] = {}
    for r in runs:
        for axis, label in r.labels:
            axes.setdefault(axis, [])
            if label not in axes[axis]:
                axes[axis].append(label)
    return runs, axes, data.get('duration_s', meta['duration_s']), sweep_runs


def _scene_runs(p: Path, data: dict, name: str) -> list[RunSpec]:
    """Return the one base run of `scene` (a path relative to the file, or a scene name)."""
    if 'scene' not in data:
        raise OptimizeError(
            f'{p}: neither sweep (with study) nor scene given; allowed: one of them'
        )
    scene = str(data['scene'])
    if not (Path(scene).is_file()) and (p.parent / scene).is_file():
        scene = str(p.parent / scene)
    return [
        RunSpec(
            name,
            (),
            scene,
            dict(data.get('overrides') or {}),
            5.0,
            tuple(data.get('replace') or ()),
        )
    ]


def _fixed_labels(p: Path, data: dict, axes: dict[str, list[str]]) -> dict[str, str]:
    """Return `fixed`: axis -> the label every design keeps (a label of that axis)."""
    fixed = {str(k): str(v) for k, v in (data.get('fixed') or {}).items()}
    for axis, label in fixed.items():
        if axis not in axes or label not in axes[axis]:
            raise OptimizeError(
                f'{p}: fixed.{axis}: {label!r} is not a label of an axis of the study; allowed: '
                + '; '.join(f'{a}: {", ".join(ls)}' for a, ls in axes.items())
            )
    return fixed


def _parameters(
    p: Path, data: dict, axes: dict[str, list[str]], fixed: dict[str, str]
) -> list[Parameter | Choice]:
    """Return the searched parameters: ranges {low, high[, scale]}, {axis} or {choices}."""
    raw = data.get('parameters')
    if not isinstance(raw, dict) or not raw:
        raise OptimizeError(
            f'{p}: parameters: allowed: a mapping name -> {{low, high}} | {{axis}} | {{choices}}'
        )
    parameters: list[Parameter | Choice] = []
    for key, body in raw.items():
        key = str(key)
        where = f'{p}: parameters.{key}'
        if not isinstance(body, dict):
            raise OptimizeError(
                f'{where}: {body!r} is not a mapping; allowed: {{low, high[, scale]}}, {{axis}} '
                f'or {{choices}}'
            )
        if 'axis' in body:
            axis = str(body['axis'])
            if axis not in axes or axis in fixed:
                raise OptimizeError(
                    f'{where}: axis {axis!r} rejected; allowed: an axis of the study not in '
                    'fixed: '
                    f'{", ".join(a for a in axes if a not in fixed)}'
                )
            parameters.append(Choice(axis, list(axes[axis]), axis=True))
        elif 'choices' in body:
            if '.' not in key or not isinstance(body['choices'], list) or len(body['choices']) < 2:
                raise OptimizeError(
                    f'{where}: choices rejected; allowed: a dotted scene key with a list of 2 or '
                    'more values'
                )
            parameters.append(Choice(key, list(body['choices'])))
        else:
            parameters.append(_range_parameter(where, key, body))
    return parameters


def _range_parameter(where: str, key: str, body: dict) -> Parameter:
    """Return a searched range low < high, linear or log-spaced (log needs low > 0)."""
    low = _number(body.get('low'), f'{where}.low', 'a finite number')
    high = _number(body.get('high'), f'{where}.high', f'a finite number above low ({low:g})')
    if high <= low:
        raise OptimizeError(f'{where}.high: {high!r} rejected; allowed: above low ({low:g})')
    scale = body.get('scale', 'linear')
    if scale not in ('linear', 'log') or (scale == 'log' and low <= 0):
        raise OptimizeError(
            f'{where}.scale: {scale!r} rejected; allowed: linear, or log with low > 0'
        )
    return Parameter(key, low, high, initial=low, log=scale == 'log')


def _derived(p: Path, data: dict, parameters: list[Parameter | Choice]) -> dict[str, str]:
    """
    Return `derived`: dotted scene key -> an expression of the numeric parameters.

    A numeric parameter without a dotted key must feed some expression, or it would change
    nothing.
    """
    numeric = {q.key for q in parameters if isinstance(q, Parameter)}
    derived = {str(k): str(v) for k, v in (data.get('derived') or {}).items()}
    for key, expr in derived.items():
        if '.' not in key:
            raise OptimizeError(f'{p}: derived.{key}: allowed: a dotted scene key')
        _check_expression(expr, numeric, f'{p}: derived.{key}')
    for q in parameters:
        if (
            isinstance(q, Parameter)
            and '.' not in q.key
            and not any(
                q.key
                in {n.id for n in ast.walk(ast.parse(e, mode='eval')) if isinstance(n, ast.Name)}
                for e in derived.values()
            )
        ):
            raise OptimizeError(
                f'{p}: parameters.{q.key}: neither a dotted scene key nor used in derived; '
                'allowed: one of them'
            )
    return derived


def _base_runs(
    p: Path,
    runs: list[RunSpec],
    axes: dict[str, list[str]],
    axis_choices: list[str],
    defaults: dict[str, str],
) -> dict[tuple, RunSpec]:
    """Return the base run of every combination of the searched axes' labels (exactly one)."""
    base_runs: dict[tuple, RunSpec] = {}
    combos = [()]
    for a in axis_choices:
        combos = [c + (lbl,) for c in combos for lbl in axes[a]]
    for combo in combos:
        want = dict(defaults, **dict(zip(axis_choices, combo)))
        match = [r for r in runs if dict(r.labels) == want]
        if len(match) != 1:
            raise OptimizeError(f'{p}: no single run of the study has the labels {want}')
        base_runs[combo] = match[0]
    return base_runs


def _check_scene_keys(spec: OptimizeSpec) -> None:
    """Refuse a searched or derived dotted key that the base scene(s) do not hold."""
    from pulsejet_sim.scene import load_scene, SceneError

    p = spec.path
    keys = [q.key if isinstance(q, Parameter) else q.name for q in spec.parameters]
    for combo, base in spec.base_runs.items():
        try:
            scene = load_scene(base.scene, dict(base.overrides), replace=base.replace)
        except (SceneError, ValueError) as err:
            raise OptimizeError(f'{p}: the base scene {base.scene!r} is refused: {err}') from None
        for key in keys + list(spec.derived):
            if '.' not in key:
                continue
            try:
                get_dotted(scene_mapping(scene), key)
            except KeyError:
                raise OptimizeError(
                    f"{p}: {key}: not a key of the scene {base.scene!r} (with the study's "
                    'overrides); allowed: a dotted key present in it'
                ) from None


def _check_corner_designs(spec: OptimizeSpec) -> None:
    """Load the designs at the bounds, so a bad key or range shows up before any run."""
    from pulsejet_sim.scene import load_scene, SceneError

    for corner in (np.zeros(len(spec.parameters)), np.ones(len(spec.parameters)) - 1e-12):
        values = spec.values(corner)
        rs = spec.run_spec(values, 'check')
        try:
            load_scene(rs.scene, dict(rs.overrides), replace=rs.replace)
        except (SceneError, ValueError) as err:
            raise OptimizeError(
                f'{spec.path}: the design {values} is refused by the scene: {err}'
            ) from None


def _compare(p: Path, data: dict) -> dict | None:
    """Return `compare` with its CSV resolved (relative to the file), or None when absent."""
    if data.get('compare') is None:
        return None
    compare = dict(data['compare'])
    csv_path = Path(str(compare.get('csv', '')))
    if not csv_path.is_absolute() and not csv_path.is_file():
        csv_path = p.parent / csv_path
    if not csv_path.is_file():
        raise OptimizeError(
            f'{p}: compare.csv: {str(compare.get("csv"))!r} not found; allowed: a CSV of '
            '`pulsejet '
            'sweep` or of the paper study (path relative to the optimisation file)'
        )
    compare['csv'] = _relative(csv_path)
    compare['where'] = {str(k): str(v) for k, v in (compare.get('where') or {}).items()}
    return compare


# ---------------------------------------------------------------- the search


@dataclass
class OptimizeResult:
    spec: OptimizeSpec
    history: list[dict]  # one per run: eval, generation, values, row
    best: dict
    wall_s: float
    executor: str
    grid: dict | None = None  # the stored grid's best (and its rerun)


def run_optimize(
    spec: OptimizeSpec,
    executor,
    max_evals: int | None = None,
    seed: int | None = None,
    progress=sys.stderr,
    executor_name: str = '',
) -> OptimizeResult:
    """
    Run differential evolution over spec's parameters.

    Each generation's runs are submitted to `executor` together (and the comparison run, if any,
    after the search).
    """
    budget = int(max_evals if max_evals is not None else spec.options['max_evals'])
    seed = int(spec.options['seed'] if seed is None else seed)
    history: list[dict] = []
    start = time.perf_counter()

    def evaluate(designs: list[np.ndarray]) -> list[float]:
        values = [spec.values(u) for u in designs]
        specs = [spec.run_spec(v, f'e{len(history) + i:03d}') for i, v in enumerate(values)]
        rows = [f.result() for f in [executor.submit(run_one, s) for s in specs]]
        costs = []
        for v, s, row in zip(values, specs, rows):
            cost = spec.cost(row)
            costs.append(cost)
            history.append(
                {'eval': len(history), 'values': v, 'row': row, 'cost': cost, 'spec': s}
            )
        if progress is not None:
            best = min(h['cost'] for h in history)
            progress.write(
                f'{len(history)}/{budget} runs, {time.perf_counter() - start:6.1f} s, best '
                f'{spec.objective} {-best if spec.sense == "max" else best:.5g}\n'
            )
            progress.flush()
        return costs

    evaluations = differential_evolution(
        evaluate,
        len(spec.parameters),
        budget,
        population=int(spec.options['population']),
        seed=seed,
        mutation=list(np.atleast_1d(spec.options['mutation'])),
        crossover=float(spec.options['crossover']),
    )
    for ev, h in zip(evaluations, history):
        h['generation'] = ev.generation
    best = min(history, key=lambda h: (h['cost'], h['eval']))
    result = OptimizeResult(spec, history, best, time.perf_counter() - start, executor_name)
    if spec.compare is not None:
        result.grid = grid_best(spec, executor)
    return result


def grid_best(spec: OptimizeSpec, executor=None) -> dict:
    """
    Return the best row of the stored grid (compare.csv filtered by compare.where).

    With compare.rerun and the sweep's run of that name available, also the same run again today.
    """
    with open(spec.compare['csv'], newline='') as fh:
        rows = [
            r
            for r in csv.DictReader(fh)
            if all(r.get(k) == v for k, v in spec.compare['where'].items())
        ]
    ok = [r for r in rows if not r.get('fault') and r.get(spec.objective) not in (None, '')]
    if not ok:
        raise OptimizeError(
            f'compare: no row of {spec.compare["csv"]} matches {spec.compare["where"]} with a '
            f'{spec.objective}'
        )
    pick = max if spec.sense == 'max' else min
    best = pick(ok, key=lambda r: float(r[spec.objective]))
    out = {
        'csv': str(spec.compare['csv']),
        'runs': len(rows),
        'best_run': best['run'],
        'best_value': float(best[spec.objective]),
    }
    if spec.compare.get('rerun') and executor is not None:
        match = [r for r in spec.sweep_runs if r.name == best['run']]
        if match:
            rs = match[0]
            row = executor.submit(
                run_one,
                RunSpec(rs.study, rs.labels, rs.scene, rs.overrides, spec.duration_s, rs.replace),
            ).result()
            out['rerun_value'] = row.metrics.get(spec.objective, math.nan)
            out['rerun_fault'] = row.fault
    return out


def scene_mapping(scene) -> dict:
    """
    Return a loaded scene as a mapping that loads again.

    Its validated sections, routine and description.
    """
    data = dict(scene.data)
    if scene.routine is not None:
        data['routine'] = dict(scene.routine)
    return data


def _relative(path: Path) -> Path:
    """
    Return path relative to the working directory when below it.

    Reports stay readable and portable.
    """
    path = Path(path).resolve()
    try:
        return path.relative_to(Path.cwd())
    except ValueError:
        return path


def _plain(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def best_scene_text(result: OptimizeResult) -> str:
    from pulsejet_sim.scene import load_scene

    rs = result.best['spec']
    scene = load_scene(rs.scene, dict(rs.overrides), replace=rs.replace)
    value = result.best['row'].metrics.get(result.spec.objective)
    header = (
        f'# Best design of `pulsejet optimize {_relative(result.spec.path)}` '
        f'({len(result.history)} runs): '
        f'{result.spec.objective} = {value!r}\n'
        + ''.join(f'#   {k} = {_plain(v)!r}\n' for k, v in result.best['values'].items())
        + f"# base scene {rs.scene!r} with the study's overrides and these values written in\n"
    )
    return header + yaml.safe_dump(scene_mapping(scene), sort_keys=False)


def write_history(result: OptimizeResult, path: Path) -> Path:
    """One row per run, deterministic columns only (no wall time): the same on any executor."""
    names = [q.key if isinstance(q, Parameter) else q.name for q in result.spec.parameters]
    derived = list(result.spec.derived)
    best_so_far = math.inf
    with open(path, 'w', newline='') as fh:
        writer = csv.writer(fh, lineterminator='\n')
        writer.writerow(
            ['eval', 'generation', *names, *derived, *METRICS, 'cost', 'best_so_far', 'fault']
        )
        for h in result.history:
            best_so_far = min(best_so_far, h['cost'])
            best_value = (
                (-best_so_far if result.spec.sense == 'max' else best_so_far)
                if math.isfinite(best_so_far)
                else ''
            )
            dv = {k: _evaluate(e, h['values']) for k, e in result.spec.derived.items()}
            writer.writerow(
                [
                    h['eval'],
                    h['generation'],
                    *[
                        (
                            repr(_plain(h['values'][n]))
                            if isinstance(h['values'][n], float)
                            else h['values'][n]
                        )
                        for n in names
                    ],
                    *[repr(dv[k]) for k in derived],
                    *[repr(h['row'].metrics[m]) if m in h['row'].metrics else '' for m in METRICS],
                    repr(h['cost']),
                    repr(best_value) if best_value != '' else '',
                    h['row'].fault,
                ]
            )
    return path


def plot_convergence(result: OptimizeResult, path: Path) -> Path:
    from matplotlib.figure import Figure  # no pyplot: the caller's backend is left alone

    spec = result.spec
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    x = [h['eval'] + 1 for h in result.history]
    y = [
        h['row'].metrics.get(spec.objective, math.nan) if not h['row'].fault else math.nan
        for h in result.history
    ]
    ax.plot(x, y, 'o', color='tab:blue', ms=4, label='run')
    faults = [h['eval'] + 1 for h in result.history if h['row'].fault]
    if faults:
        ax.plot(
            faults,
            [np.nanmin(y) if np.isfinite(np.nanmin(y)) else 0] * len(faults),
            'x',
            color='tab:red',
            label='fault',
        )
    pick = np.fmax if spec.sense == 'max' else np.fmin
    ax.step(
        x, pick.accumulate(np.array(y, dtype=float)), where='post', color='k', label='best so far'
    )
    for g in sorted({h['generation'] for h in result.history})[1:]:
        ax.axvline(
            min(h['eval'] for h in result.history if h['generation'] == g) + 0.5,
            color='0.85',
            lw=0.8,
        )
    if result.grid:
        ax.axhline(
            result.grid['best_value'],
            color='tab:green',
            ls='--',
            label=f'grid best, stored ({result.grid["runs"]} runs)',
        )
        if 'rerun_value' in result.grid:
            ax.axhline(
                result.grid['rerun_value'],
                color='tab:olive',
                ls=':',
                label='grid best, rerun today',
            )
    ax.set_xlabel('run')
    ax.set_ylabel(spec.objective)
    ax.set_title(
        f'{spec.name}: differential evolution, {len(result.history)} runs (grey: generations)'
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def results_dict(result: OptimizeResult) -> dict:
    spec, best = result.spec, result.best
    out = {
        'name': spec.name,
        'file': str(_relative(spec.path)),
        'objective': spec.objective,
        'sense': spec.sense,
        'runs': len(result.history),
        'executor': result.executor,
        'wall_s': round(result.wall_s, 2),
        'best': {
            'eval': best['eval'],
            'value': best['row'].metrics.get(spec.objective),
            'values': {k: _plain(v) for k, v in best['values'].items()},
            'derived': {k: _evaluate(e, best['values']) for k, e in spec.derived.items()},
            'metrics': dict(best['row'].metrics),
        },
    }
    if result.grid:
        out['grid'] = dict(result.grid)
        value = best['row'].metrics.get(spec.objective, math.nan)
        better = (lambda a, b: a >= b) if spec.sense == 'max' else (lambda a, b: a <= b)
        out['grid']['optimum_at_least_as_good_as_stored'] = bool(
            better(value, result.grid['best_value'])
        )
        if 'rerun_value' in result.grid:
            out['grid']['optimum_at_least_as_good_as_rerun'] = bool(
                better(value, result.grid['rerun_value'])
            )
        out['grid']['runs_used_vs_grid'] = f'{len(result.history)} <= {result.grid["runs"]}'
    return out


def write_results(result: OptimizeResult, out_dir: str | Path) -> dict[str, Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        'scene': out / 'best_scene.yaml',
        'history': out / 'history.csv',
        'plot': out / 'convergence.png',
        'results': out / 'optimize_results.yaml',
    }
    paths['scene'].write_text(best_scene_text(result))
    write_history(result, paths['history'])
    plot_convergence(result, paths['plot'])
    paths['results'].write_text(yaml.safe_dump(results_dict(result), sort_keys=False))
    return paths


def format_summary(result: OptimizeResult) -> str:
    d = results_dict(result)
    lines = [
        f'{d["name"]}: {d["runs"]} runs on {d["executor"]} in {d["wall_s"]:.1f} s',
        f'best ({d["objective"]}, {d["sense"]}): {d["best"]["value"]!r} at run '
        f'{d["best"]["eval"]}',
    ]
    lines += [f'  {k} = {v!r}' for k, v in d['best']['values'].items()]
    lines += [f'  {k} = {v:.6g} (derived)' for k, v in d['best']['derived'].items()]
    if 'grid' in d:
        g = d['grid']
        lines.append(
            f'grid ({g["runs"]} runs, {g["csv"]}): best {g["best_value"]!r} ({g["best_run"]})'
            + (f', rerun today {g["rerun_value"]!r}' if 'rerun_value' in g else '')
        )
        lines.append(
            '  optimum at least as good as the stored grid best: '
            f'{g["optimum_at_least_as_good_as_stored"]}'
            + (
                f'; as its rerun: {g["optimum_at_least_as_good_as_rerun"]}'
                if 'rerun_value' in g
                else ''
            )
        )
    return '\n'.join(lines)


def main_optimize(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog='pulsejet optimize',
        description='Search scene parameters within bounds (differential evolution).',
    )
    parser.add_argument('file', help='optimisation YAML path or a name under config/optimize/')
    parser.add_argument(
        '--out', default=None, help='output folder (default: runs/optimize/<name>)'
    )
    parser.add_argument(
        '--max-evals',
        type=int,
        default=None,
        help="runs at most (default: the file's options.max_evals)",
    )
    parser.add_argument(
        '--seed', type=int, default=None, help="random seed (default: the file's options.seed)"
    )
    parser.add_argument(
        '--workers', type=int, default=None, help='local processes (default: all cores)'
    )
    parser.add_argument(
        '--scheduler', default=None, metavar='tcp://HOST:PORT', help='run on this Dask scheduler'
    )
    parser.add_argument(
        '--dask-workers',
        type=int,
        default=None,
        metavar='N',
        help='run on a local Dask cluster of N worker processes',
    )
    args = parser.parse_args(argv)
    for flag, value in (
        ('--max-evals', args.max_evals),
        ('--workers', args.workers),
        ('--dask-workers', args.dask_workers),
    ):
        if value is not None and value < 1:
            print(
                f'pulsejet optimize: {flag} {value} rejected; allowed: 1 or more', file=sys.stderr
            )
            return 2
    try:
        spec = load_optimize(args.file)
    except (OptimizeError, yaml.YAMLError) as err:
        print(f'pulsejet optimize: {err}', file=sys.stderr)
        return 2
    label = executor_label(args.workers, args.scheduler, args.dask_workers)
    print(
        f'{spec.name}: {len(spec.parameters)} parameters, at most '
        f'{args.max_evals or spec.options["max_evals"]} runs of {spec.duration_s:g} s on {label}'
    )
    try:
        with open_executor(args.workers, args.scheduler, args.dask_workers) as executor:
            result = run_optimize(spec, executor, args.max_evals, args.seed, executor_name=label)
    except SweepError as err:
        print(f'pulsejet optimize: {err}', file=sys.stderr)
        return 2
    paths = write_results(result, args.out or Path('runs') / 'optimize' / spec.name)
    print(format_summary(result))
    for key, path in paths.items():
        print(f'{key}: {path}')
    return 0


__all__ = [
    'OptimizeError',
    'OptimizeSpec',
    'OptimizeResult',
    'differential_evolution',
    'load_optimize',
    'run_optimize',
    'write_results',
    'write_history',
    'plot_convergence',
    'main_optimize',
]


# ---------------------------------------------------------------- routines: cost of transport


def vehicle_mass_kg(scene) -> float:
    """Return the vehicle's dry mass, kg (lumped: shell + payload; shell: vehicle.mass_kg)."""
    if getattr(scene.model, 'name', '') == 'lumped':
        return scene.model.dry_mass_kg
    return float((scene.data.get('vehicle') or {}).get('mass_kg', math.nan))


def routine_run(scene: str, routine: dict | None, duration_s: float) -> dict:
    """
    Run `scene` offline with its routine block updated by `routine`, and measure it.

    This is the executor's unit of work when a routine is trained. It measures:

    - distance_m: the integral of the forward velocity over the run (sum of the published samples
      times the publication period, `metrics.distance_from_samples_m`, as `pulsejet sweep`
      measures it);
    - work_j: the actuation work put in, `in_actuation_work` of the energy ledger at the end;
    - mass_kg: total mass moved = the vehicle's dry mass + the time-mean fluid mass in the cavity
      (the mass this cost of transport states; the environments use the rest cavity's water);
    - cost_of_transport: `metrics.cost_of_transport`, work_j / (mass_kg * 9.81 m/s^2 *
      distance_m), dimensionless (inf when the vehicle did not move forward).
    """
    from pulsejet_sim.analysis import metrics
    from pulsejet_sim.scene import load_scene
    from pulsejet_sim.studies.runner import Drive

    out = {
        'fault': '',
        'distance_m': math.nan,
        'work_j': math.nan,
        'mass_kg': math.nan,
        'cost_of_transport': math.inf,
    }
    try:
        sc = load_scene(scene, {'routine': dict(routine)} if routine else None)
        drive = Drive(sc, duration_s)
    except ValueError as err:
        out['fault'] = f'refused: {err}'
        return out
    speeds, fluid = [], []
    for _, _, obs in drive:
        speeds.append(obs.velocity_m_s)
        fluid.append(obs.fluid_mass_kg)
    out['fault'] = drive.fault or ''
    if not speeds:
        return out
    dt_pub = drive.batch * drive.sim.model.dt_s
    out['distance_m'] = metrics.distance_from_samples_m(speeds, dt_pub)
    out['work_j'] = float(drive.sim.energy_ledger()['in_actuation_work'])
    out['mass_kg'] = vehicle_mass_kg(sc) + sum(fluid) / len(fluid)
    out['simulated_s'] = drive.sim.time_s
    if out['distance_m'] > 0 and not out['fault']:
        # no minimum distance: a run that did not move forward keeps the inf set above
        out['cost_of_transport'] = float(
            metrics.cost_of_transport(out['work_j'], out['distance_m'], out['mass_kg'])
        )
    return out
