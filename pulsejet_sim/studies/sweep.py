"""
`pulsejet sweep`: a grid of scene variants run in parallel, one CSV row and one bar per run.

Runs are submitted through a `concurrent.futures.Executor` (`submit` + `as_completed`): the local
process pool is the default; `open_executor` also gives Dask's executor (`distributed.Client(...)
.get_executor()`) on a running scheduler (`--scheduler tcp://HOST:PORT`) or on a local Dask
cluster of worker processes (`--dask-workers N`), without touching scenes or models. Each run is a
plain, picklable `RunSpec` evaluated by `run_one`, which imports no ROS. Dask (`dask[distributed]`)
is imported only when one of those options is used.

Sweep file (YAML)::

    name: lumped_stiffness
    duration_s: 6.0
    metric: peak_speed_m_s        # what the bar plot compares
    studies:                      # one or more; each is the product of its axes
      main:
        base: escape              # scene name or path
        axes:
          stiffness:              # axis name -> {label: overrides merged into the scene}
            soft: {material: {stiffness_n_m: 1000}}
            paper: {material: {stiffness_n_m: 2094}}
          coupling:
            consistent: {options: {coupling: consistent}}
            paper: {options: {coupling: paper}}

An axis value may also hold `scene: OTHER` to switch the base scene (e.g. cone vs ellipsoid), and a
study may list `replace: [section, ...]`: those sections of the base scene are replaced whole by
the overrides (e.g. a muscle actuation block instead of a cable one) rather than merged into.
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import contextlib
import csv
from dataclasses import asdict, dataclass, field
import itertools
import multiprocessing
import os
from pathlib import Path
import sys
import time
from typing import Any, Callable, Iterator, Mapping

import yaml

METRICS = (
    'peak_speed_m_s',
    'mean_speed_m_s',
    'distance_m',
    'peak_thrust_n',
    'max_radius_m',
    'volume_min_m3',
    'volume_max_m3',
    'closure_relative',
)


class SweepError(ValueError):
    """A sweep file that cannot be run (names the key, the value and what is allowed)."""


@dataclass(frozen=True)
class RunSpec:
    study: str
    labels: tuple[tuple[str, str], ...]  # (axis, label) pairs
    scene: str
    overrides: Mapping[str, Any]
    duration_s: float
    replace: tuple[str, ...] = ()  # base-scene sections the overrides replace whole

    @property
    def name(self) -> str:
        return '/'.join([self.study] + [label for _, label in self.labels])


@dataclass
class RunRow:
    name: str
    study: str
    labels: dict[str, str]
    fault: str = ''
    wall_s: float = 0.0
    simulated_s: float = 0.0
    metrics: dict[str, float] = field(default_factory=dict)


def merge(base: Mapping, override: Mapping) -> dict:
    from pulsejet_sim.scene import merge as scene_merge

    return scene_merge(dict(base), dict(override))


def run_one(spec: RunSpec, on_batch: Callable[[Any], None] | None = None) -> RunRow:
    """
    Run one variant without ROS and measure it (the executor's unit of work).

    `on_batch(sim)`, if given, is called with the Simulation after each published batch, for a
    caller's own measurements beside the metrics.
    """
    from pulsejet_sim.analysis import metrics
    from pulsejet_sim.scene import load_scene
    from pulsejet_sim.studies.runner import Drive

    start = time.perf_counter()
    row = RunRow(name=spec.name, study=spec.study, labels=dict(spec.labels))
    try:
        drive = Drive(
            load_scene(spec.scene, dict(spec.overrides), replace=spec.replace), spec.duration_s
        )
    except ValueError as err:
        row.fault = f'refused: {err}'
        return row
    speeds, thrusts, radii, volumes = [], [], [], []
    for _, _, obs in drive:
        speeds.append(obs.velocity_m_s)
        thrusts.append(obs.thrust_n)
        radii.append(obs.mantle_radius_m)
        volumes.append(obs.volume_m3)
        if on_batch is not None:
            on_batch(drive.sim)
    dt_pub = drive.batch * drive.sim.model.dt_s
    row.fault = drive.fault or ''
    row.wall_s = time.perf_counter() - start
    row.simulated_s = drive.sim.time_s
    if speeds:
        row.metrics = {
            'peak_speed_m_s': metrics.peak_speed_m_s(speeds),
            # the published samples are equally spaced: their mean, not a time integral
            'mean_speed_m_s': metrics.sample_mean_speed_m_s(speeds),
            'distance_m': metrics.distance_from_samples_m(speeds, dt_pub),
            'peak_thrust_n': max(thrusts),
            'max_radius_m': max(radii),
            'volume_min_m3': min(volumes),
            'volume_max_m3': max(volumes),
            'closure_relative': drive.sim.energy_ledger()['closure_relative'],
        }
    return row


def load_sweep(path: str | os.PathLike) -> tuple[dict, list[RunSpec]]:
    """Read a sweep file and expand it into runs."""
    from pulsejet_sim.scene.paths import read_config_file

    p, data = read_config_file(path, 'sweeps', 'sweep', SweepError)
    if not isinstance(data, dict) or 'studies' not in data:
        raise SweepError(
            f'{p}: top level must be a mapping with key studies (and name, duration_s, metric)'
        )
    unknown = set(data) - {'name', 'description', 'duration_s', 'metric', 'studies'}
    if not isinstance(data['studies'], dict):
        raise SweepError(
            f'{p}: studies: allowed: a mapping of study name -> {{base, overrides, replace, axes}}'
        )
    if unknown:
        raise SweepError(
            f'{p}: {sorted(unknown)[0]}: unknown key; allowed: name, description, duration_s, '
            'metric, studies'
        )
    duration = data.get('duration_s', 5.0)
    if (
        isinstance(duration, bool)
        or not isinstance(duration, (int, float))
        or not (0 < duration < 1e6)
    ):
        raise SweepError(
            f'{p}: duration_s: {duration!r} rejected; allowed: a number of seconds in (0, 1e6)'
        )
    metric = data.get('metric', 'peak_speed_m_s')
    if metric not in METRICS:
        raise SweepError(
            f'{p}: metric: {metric!r} is not known; allowed: one of {", ".join(METRICS)}'
        )
    runs: list[RunSpec] = []
    for study, body in data['studies'].items():
        if (
            not isinstance(body, dict)
            or 'base' not in body
            or not isinstance(body.get('axes', {}), dict)
        ):
            raise SweepError(
                f'{p}: studies.{study}: allowed: a mapping with base (a scene) and axes'
            )
        axes = body.get('axes') or {}
        for axis, options in axes.items():
            if not isinstance(options, dict) or not options:
                raise SweepError(
                    f'{p}: studies.{study}.axes.{axis}: {options!r} rejected; allowed: a mapping '
                    'of '
                    f'label -> overrides (a mapping)'
                )
            for label, values in options.items():
                if values is not None and not isinstance(values, dict):
                    raise SweepError(
                        f'{p}: studies.{study}.axes.{axis}.{label}: {values!r} rejected; allowed: '
                        f'a mapping of scene overrides (and scene: NAME)'
                    )
        for key in ('overrides',):
            if body.get(key) is not None and not isinstance(body[key], dict):
                raise SweepError(
                    f'{p}: studies.{study}.{key}: {body[key]!r} rejected; allowed: a mapping'
                )
        replace = body.get('replace') or ()
        if not isinstance(replace, (list, tuple)) or not all(isinstance(r, str) for r in replace):
            raise SweepError(
                f'{p}: studies.{study}.replace: {replace!r} rejected; allowed: a list of section '
                'names'
            )
        choices = [
            [(axis, label, values or {}) for label, values in options.items()]
            for axis, options in axes.items()
        ]
        for combo in itertools.product(*choices) if choices else [()]:
            scene = body['base']
            overrides: dict = dict(body.get('overrides') or {})
            for _, _, values in combo:
                values = dict(values)
                scene = values.pop('scene', scene)
                overrides = merge(overrides, values)
            runs.append(
                RunSpec(
                    study=str(study),
                    labels=tuple((a, str(lbl)) for a, lbl, _ in combo),
                    scene=str(scene),
                    overrides=overrides,
                    duration_s=float(duration),
                    replace=tuple(body.get('replace') or ()),
                )
            )
    meta = {
        'name': data.get('name', p.stem),
        'metric': metric,
        'duration_s': float(duration),
        'path': str(p),
    }
    return meta, runs


def local_executor(workers: int | None = None) -> futures.Executor:
    """
    Return a process pool on the local cores.

    'spawn': workers start clean, as remote ones would.
    """
    return futures.ProcessPoolExecutor(
        max_workers=workers or os.cpu_count() or 1, mp_context=multiprocessing.get_context('spawn')
    )


@contextlib.contextmanager
def open_executor(
    workers: int | None = None, scheduler: str | None = None, dask_workers: int | None = None
) -> Iterator[futures.Executor]:
    """
    Open the executor a sweep or an optimisation submits its runs to (closed on exit).

    One of:

    - scheduler='tcp://HOST:PORT': a running Dask scheduler (`dask scheduler` + `dask worker`, or
      dask-jobqueue on SLURM); its workers need pulsejet importable (the same checkout installed);
    - dask_workers=N: a local Dask cluster of N worker processes, one thread each;
    - otherwise: the local process pool of `workers` processes (default: all cores).
    Dask's executor is `Client.get_executor(pure=False)`: every submission runs (no deduplication).
    """
    if scheduler is not None and dask_workers is not None:
        raise SweepError('--scheduler and --dask-workers exclude each other; allowed: one of them')
    if scheduler is None and dask_workers is None:
        executor = local_executor(workers)
        try:
            yield executor
        finally:
            executor.shutdown(cancel_futures=True)
        return
    try:
        import distributed
    except ImportError as err:  # the optional extra is missing
        raise SweepError(
            f'Dask executor requested but dask.distributed is not installed ({err}); allowed: '
            'pip install "dask[distributed]" (pinned in requirements.txt)'
        ) from err
    cluster = None
    if dask_workers is not None:
        if dask_workers < 1:
            raise SweepError(f'--dask-workers {dask_workers} rejected; allowed: 1 or more')
        cluster = distributed.LocalCluster(
            n_workers=dask_workers, threads_per_worker=1, processes=True, dashboard_address=':0'
        )
        client = distributed.Client(cluster)
    else:
        try:
            client = distributed.Client(scheduler, timeout='20s')
        except (OSError, TimeoutError) as err:
            raise SweepError(
                f'--scheduler {scheduler!r}: cannot connect ({err}); allowed: the address of a '
                'running dask scheduler, e.g. tcp://127.0.0.1:8786'
            ) from err
    try:
        yield client.get_executor(pure=False)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def executor_label(
    workers: int | None = None, scheduler: str | None = None, dask_workers: int | None = None
) -> str:
    if scheduler is not None:
        return f'the Dask scheduler {scheduler}'
    if dask_workers is not None:
        return f'a local Dask cluster of {dask_workers} worker processes'
    return f'{workers or os.cpu_count()} local processes'


def run_sweep(
    runs: list[RunSpec],
    executor: futures.Executor | None = None,
    workers: int | None = None,
    progress=sys.stderr,
) -> list[RunRow]:
    """
    Run every spec through `executor` (default: a local process pool).

    Returns the rows in the runs' order.
    """
    own = executor is None
    executor = executor or local_executor(workers)
    rows: dict[int, RunRow] = {}
    bar = Progress(len(runs), progress)
    try:
        pending = {executor.submit(run_one, spec): i for i, spec in enumerate(runs)}
        for done in futures.as_completed(pending):
            rows[pending[done]] = done.result()
            bar.update()
    finally:
        bar.close()
        if own:
            executor.shutdown(cancel_futures=True)
    return [rows[i] for i in range(len(runs))]


class Progress:
    """
    Progress of `total` runs on `stream` (None: silent).

    A tqdm bar on a terminal; in a log (not a terminal) one plain line per tenth of the runs, never
    carriage returns.
    """

    def __init__(self, total: int, stream=sys.stderr):
        self.total, self.stream, self.done = total, stream, 0
        self.start = time.perf_counter()
        self.bar = None
        if stream is not None and getattr(stream, 'isatty', lambda: False)():
            from tqdm import tqdm

            self.bar = tqdm(total=total, file=stream, unit='run', dynamic_ncols=True)

    def update(self) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(1)
        elif self.stream is not None and (
            self.done == self.total or self.done % max(1, self.total // 10) == 0
        ):
            elapsed = time.perf_counter() - self.start
            self.stream.write(
                f'{self.done}/{self.total} runs, {elapsed:.1f} s elapsed, '
                f'~{elapsed / self.done * (self.total - self.done):.1f} s left\n'
            )
            self.stream.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def write_csv(rows: list[RunRow], path: Path, timing: bool = True) -> Path:
    """
    Write one row per run.

    wall_s (the only column that differs between two runs of the same sweep) is left out with
    timing=False, so the file is then reproducible byte for byte on any executor.
    """
    axes = sorted({a for r in rows for a in r.labels})
    with open(path, 'w', newline='') as fh:
        writer = csv.writer(fh)
        writer.writerow(
            ['run', 'study']
            + axes
            + list(METRICS)
            + ['simulated_s']
            + (['wall_s'] if timing else [])
            + ['fault']
        )
        for r in rows:
            writer.writerow(
                [r.name, r.study]
                + [r.labels.get(a, '') for a in axes]
                + [repr(r.metrics[m]) if m in r.metrics else '' for m in METRICS]
                + [f'{r.simulated_s:.6g}']
                + ([f'{r.wall_s:.3f}'] if timing else [])
                + [r.fault]
            )
    return path


def plot_bars(rows: list[RunRow], metric: str, path: Path) -> Path:
    from matplotlib.figure import Figure  # no pyplot: the caller's backend is left alone

    studies = list(dict.fromkeys(r.study for r in rows))
    fig = Figure(figsize=(max(8, 0.3 * len(rows)), 3.5 * len(studies)))
    axes = fig.subplots(len(studies), 1, squeeze=False)
    for ax, study in zip(axes[:, 0], studies):
        group = [r for r in rows if r.study == study]
        values = [r.metrics.get(metric, 0.0) for r in group]
        colours = ['tab:red' if r.fault else 'tab:blue' for r in group]
        ax.bar(range(len(group)), values, color=colours)
        ax.set_xticks(range(len(group)))
        ax.set_xticklabels(
            ['/'.join(r.labels.values()) for r in group], rotation=70, ha='right', fontsize=7
        )
        ax.set_ylabel(metric)
        ax.set_title(f'{study} (red: fault)')
        ax.grid(axis='y', alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def main_sweep(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog='pulsejet sweep', description='Run a grid of scenes in parallel.'
    )
    parser.add_argument('sweep', help='sweep YAML path or a name under config/sweeps/')
    parser.add_argument(
        '--workers', type=int, default=None, help='local processes (default: all cores)'
    )
    parser.add_argument(
        '--scheduler',
        default=None,
        metavar='tcp://HOST:PORT',
        help='run on this Dask scheduler (dask.distributed executor) instead of local processes',
    )
    parser.add_argument(
        '--dask-workers',
        type=int,
        default=None,
        metavar='N',
        help='run on a local Dask cluster of N worker processes (one thread each)',
    )
    parser.add_argument(
        '--out', default='runs/sweeps', help='output folder for the CSV and the plot'
    )
    parser.add_argument(
        '--duration', type=float, default=None, help="override the sweep's duration_s"
    )
    parser.add_argument(
        '--no-timing',
        action='store_true',
        help='leave the wall_s column out of the CSV (a reproducible file on any executor)',
    )
    args = parser.parse_args(argv)
    try:
        meta, runs = load_sweep(args.sweep)
    except (SweepError, yaml.YAMLError) as err:
        print(f'pulsejet sweep: {err}', file=sys.stderr)
        return 2
    if args.workers is not None and args.workers < 1:
        print(
            f'pulsejet sweep: --workers {args.workers} rejected; allowed: 1 or more',
            file=sys.stderr,
        )
        return 2
    if args.duration is not None:
        runs = [
            RunSpec(r.study, r.labels, r.scene, r.overrides, args.duration, r.replace)
            for r in runs
        ]
    if args.dask_workers is not None and args.dask_workers < 1:
        print(
            f'pulsejet sweep: --dask-workers {args.dask_workers} rejected; allowed: 1 or more',
            file=sys.stderr,
        )
        return 2
    if args.scheduler is not None and args.dask_workers is not None:
        print(
            'pulsejet sweep: --scheduler and --dask-workers exclude each other; allowed: one of '
            'them',
            file=sys.stderr,
        )
        return 2
    print(
        f'{meta["name"]}: {len(runs)} runs of {runs[0].duration_s if runs else 0:g} s on '
        f'{executor_label(args.workers, args.scheduler, args.dask_workers)}'
    )
    try:
        with open_executor(args.workers, args.scheduler, args.dask_workers) as executor:
            rows = run_sweep(runs, executor=executor)
    except SweepError as err:
        print(f'pulsejet sweep: {err}', file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(rows, out / f'{meta["name"]}.csv', timing=not args.no_timing)
    png_path = plot_bars(rows, meta['metric'], out / f'{meta["name"]}.png')
    ranked = sorted((r for r in rows if r.metrics), key=lambda r: -r.metrics[meta['metric']])
    print(f'top runs by {meta["metric"]}:')
    for r in ranked[:5]:
        print(f'  {r.metrics[meta["metric"]]:.4g}  {r.name}')
    faults = [r for r in rows if r.fault]
    for r in faults:
        print(f'  FAULT {r.name}: {r.fault}')
    print(f'table: {csv_path}\nplot:  {png_path}')
    return 0


__all__ = [
    'RunSpec',
    'RunRow',
    'run_one',
    'load_sweep',
    'run_sweep',
    'local_executor',
    'open_executor',
    'executor_label',
    'write_csv',
    'plot_bars',
    'main_sweep',
    'asdict',
]
