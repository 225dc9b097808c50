"""
Train a pump/valve routine for cost of transport, offline, with differential evolution.

Save it as a scene that `sim_node` and `controller_node` load as they are.

    .venv/bin/python examples/train_routine.py                   # ~1-3 min on 2 cores
    .venv/bin/python examples/train_routine.py --dask-workers 2  # the same on a local Dask cluster
    .venv/bin/python examples/train_routine.py --scheduler tcp://HOST:8786

Cost of transport (dimensionless, lower is better) of a run of `--duration` simulated seconds from
rest: the actuation work (`in_actuation_work` of the energy ledger: the pump's work) divided by
(total mass x 9.81 m/s^2 x distance), the total mass being the vehicle's dry mass plus the
time-mean fluid mass in its cavity, the distance the integral of the forward velocity
(`pulsejet_sim.studies.optimize.routine_run`). The routine (`PumpValveRoutine`, the lumped model's
pump/valve state machine of `pulsejet_sim.routines`) inflates for `inflate_s` at
`pump_flow_m3_s`, holds `hold_s`, jets `jet_s`, and repeats; the inflation is timed
(`target_volume_m3: 0`), so the live controller's commands depend on simulated time alone.

Constraint: the trained routine must swim at least as far as the scene's own routine in the same
time (`--min-distance-share 1.0` of its distance); without it the cheapest "swimming" is a
barely moving vehicle. A design short of it costs its cost of transport plus the missing share
of the distance (a soft penalty, so the search is led back to feasible designs).

The search is `pulsejet_sim.studies.optimize.differential_evolution` (gradient-free, no
deep-learning stack), each generation's runs on the executor. Outputs (`--out`, default
examples/results/):
- `pump_cycle_trained.yaml`: the scene with the trained routine written in, e.g.
      .venv/bin/sim_node --ros-args -p scene:=examples/results/pump_cycle_trained.yaml
      .venv/bin/controller_node --ros-args -p scene:=examples/results/pump_cycle_trained.yaml
- `train_routine.yaml`: the trained values, the scene's own routine and the trained one measured
  over the same duration (distance, work, mass, cost of transport), the runs used;
- `train_routine_history.csv`: one row per run.
`test/test_trained_routine.py` runs the stored scene through controller_node against sim_node over
ROS (lockstep), records it to MCAP and checks the live distance against the offline one (2 %).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import sys
import time

from pulsejet_sim.studies.optimize import (
    differential_evolution, routine_run, scene_mapping
)
from pulsejet_sim.studies.sweep import executor_label, open_executor, SweepError
import yaml

#: routine field -> (low, high): the searched box
BOUNDS = {
    'inflate_s': (0.2, 2.0),
    'pump_flow_m3_s': (0.5e-3, 5.0e-3),
    'hold_s': (0.0, 0.5),
    'jet_s': (0.2, 5.0),
}
FIXED = {
    'kind': 'pump_valve',
    'target_volume_m3': 0.0,
    'valve_opening': 1.0,
    'cycles': 0,
    'start_delay_s': 0.0,
}
OUT = Path(__file__).resolve().parent / 'results'


def routine_of(unit) -> dict:
    values = {k: lo + float(u) * (hi - lo) for (k, (lo, hi)), u in zip(BOUNDS.items(), unit)}
    return dict(
        FIXED, **{k: float(f'{v:.6g}') for k, v in values.items()}
    )  # what the YAML will hold


def penalised(res: dict, min_distance_m: float) -> float:
    cot = res['cost_of_transport']
    if not math.isfinite(cot):
        return math.inf
    return (
        cot + max(0.0, (min_distance_m - res['distance_m']) / min_distance_m)
        if min_distance_m > 0
        else cot
    )


def train(
    scene: str,
    duration_s: float,
    max_evals: int,
    population: int,
    seed: int,
    executor,
    min_distance_m: float = 0.0,
    progress=sys.stderr,
) -> tuple[dict, list[dict]]:
    history: list[dict] = []
    start = time.perf_counter()

    def evaluate(designs):
        routines = [routine_of(u) for u in designs]
        results = [
            f.result()
            for f in [executor.submit(routine_run, scene, r, duration_s) for r in routines]
        ]
        for r, res in zip(routines, results):
            history.append(
                {
                    'eval': len(history),
                    'routine': r,
                    **res,
                    'cost': penalised(res, min_distance_m),
                    'feasible': res['distance_m'] >= min_distance_m,
                }
            )
        best = min(h['cost'] for h in history)
        progress.write(
            f'{len(history)}/{max_evals} runs, {time.perf_counter() - start:5.1f} s, '
            f'best cost {best:.5g}\n'
        )
        return [h['cost'] for h in history[-len(results):]]

    evaluations = differential_evolution(
        evaluate, len(BOUNDS), max_evals, population=population, seed=seed
    )
    for ev, h in zip(evaluations, history):
        h['generation'] = ev.generation
    best = min(history, key=lambda h: (h['cost'], h['eval']))
    return best, history


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument(
        '--scene', default='pump_cycle', help='lumped scene with a pump_valve routine'
    )
    parser.add_argument('--duration', type=float, default=8.0, help='simulated seconds per run')
    parser.add_argument('--max-evals', type=int, default=160)
    parser.add_argument('--population', type=int, default=12)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument(
        '--min-distance-share',
        type=float,
        default=1.0,
        help="swim at least this share of the scene routine's distance (0: no constraint)",
    )
    parser.add_argument('--out', default=str(OUT))
    parser.add_argument('--workers', type=int, default=None)
    parser.add_argument('--dask-workers', type=int, default=None)
    parser.add_argument('--scheduler', default=None)
    args = parser.parse_args(argv)
    from pulsejet_sim.scene import load_scene

    label = executor_label(args.workers, args.scheduler, args.dask_workers)
    print(
        f'training the routine of {args.scene} for cost of transport: {args.max_evals} runs of '
        f'{args.duration:g} s on {label}'
    )
    wall = time.perf_counter()
    try:
        with open_executor(args.workers, args.scheduler, args.dask_workers) as executor:
            baseline = executor.submit(routine_run, args.scene, None, args.duration).result()
            min_distance = args.min_distance_share * baseline['distance_m']
            best, history = train(
                args.scene,
                args.duration,
                args.max_evals,
                args.population,
                args.seed,
                executor,
                min_distance,
            )
    except SweepError as err:
        print(f'train_routine: {err}', file=sys.stderr)
        return 2
    wall = time.perf_counter() - wall
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = load_scene(args.scene, {'routine': best['routine']})
    scene_path = out / f'{Path(args.scene).stem}_trained.yaml'
    metrics = ('distance_m', 'work_j', 'mass_kg', 'cost_of_transport')
    scene_path.write_text(
        f'# {args.scene} with its pump/valve routine trained for cost of transport by'
        f' examples/train_routine.py\n# ({len(history)} offline runs of {args.duration:g} s,'
        f' differential evolution, seed {args.seed}):\n# cost of transport'
        f' {best["cost_of_transport"]:.5g} (the scene\'s own routine:'
        f' {baseline["cost_of_transport"]:.5g}), distance {best["distance_m"]:.5g} m in'
        f' {args.duration:g} s\n' + yaml.safe_dump(scene_mapping(scene), sort_keys=False)
    )
    summary = {
        'scene': args.scene,
        'duration_s': args.duration,
        'runs': len(history),
        'seed': args.seed,
        'executor': label,
        'wall_s': round(wall, 1),
        'bounds': {k: list(v) for k, v in BOUNDS.items()},
        'min_distance_m': min_distance,
        'feasible': bool(best['feasible']),
        'trained_routine': best['routine'],
        'trained': {k: best[k] for k in metrics},
        'scene_routine': {k: baseline[k] for k in metrics},
        'trained_scene': scene_path.name,
    }
    (out / 'train_routine.yaml').write_text(yaml.safe_dump(summary, sort_keys=False))
    with open(out / 'train_routine_history.csv', 'w', newline='') as fh:
        writer = csv.writer(fh, lineterminator='\n')
        writer.writerow(['eval', 'generation', *BOUNDS, *metrics, 'cost', 'feasible', 'fault'])
        for h in history:
            writer.writerow(
                [
                    h['eval'],
                    h['generation'],
                    *[repr(h['routine'][k]) for k in BOUNDS],
                    *[repr(h[k]) for k in metrics],
                    repr(h['cost']),
                    h['feasible'],
                    h['fault'],
                ]
            )
    print(
        f'scene routine:   cost of transport {baseline["cost_of_transport"]:.5g}, distance '
        f'{baseline["distance_m"]:.4g} m, work {baseline["work_j"]:.4g} J'
    )
    print(
        f'trained routine: cost of transport {best["cost_of_transport"]:.5g}, distance '
        f'{best["distance_m"]:.4g} m, work {best["work_j"]:.4g} J'
    )
    print('  ' + ', '.join(f'{k}={best["routine"][k]:g}' for k in BOUNDS))
    print(
        f'{len(history)} runs in {wall:.1f} s (distance at least {min_distance:.4g} m:'
        f' {"met" if best["feasible"] else "NOT met"}) -> {scene_path},'
        f' {out / "train_routine.yaml"}'
    )
    return 0 if best['feasible'] and math.isfinite(best['cost_of_transport']) else 1


if __name__ == '__main__':
    sys.exit(main())
