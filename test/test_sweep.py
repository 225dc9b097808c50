"""`pulsejet sweep`: grid expansion, any concurrent.futures executor, CSV and plot."""

import concurrent.futures as futures
import csv
import subprocess
import sys

from pulsejet_sim.studies.sweep import load_sweep, run_sweep, SweepError, write_csv
import pytest

SWEEP = """
name: tiny
duration_s: 2.0
metric: peak_speed_m_s
studies:
  escape:
    base: escape
    axes:
      stiffness:
        soft: {material: {stiffness_n_m: 1000}}
        stiff: {material: {stiffness_n_m: 4000}}
      drag:
        with: {}
        without: {terms: {drag: false}}
  cycle:
    base: pump_cycle
"""


def test_grid_expands_to_the_product_of_axes(tmp_path):
    path = tmp_path / 'tiny.yaml'
    path.write_text(SWEEP)
    meta, runs = load_sweep(path)
    assert meta['name'] == 'tiny' and len(runs) == 5
    assert [r.name for r in runs][:4] == [
        'escape/soft/with',
        'escape/soft/without',
        'escape/stiff/with',
        'escape/stiff/without',
    ]
    assert runs[1].overrides == {'material': {'stiffness_n_m': 1000}, 'terms': {'drag': False}}
    assert runs[4].scene == 'pump_cycle' and runs[4].labels == ()


def test_any_executor_runs_the_grid_and_the_physics_orders_the_results(tmp_path):
    path = tmp_path / 'tiny.yaml'
    path.write_text(SWEEP)
    _, runs = load_sweep(path)
    with futures.ThreadPoolExecutor(max_workers=2) as pool:  # stands in for a cluster client
        rows = run_sweep(runs, executor=pool, progress=None)
    by_name = {r.name: r for r in rows}
    assert not any(r.fault for r in rows)
    # a stiffer shell stores 4x the energy at the same inflation and swims faster
    assert (
        by_name['escape/stiff/with'].metrics['peak_speed_m_s']
        > 1.5 * by_name['escape/soft/with'].metrics['peak_speed_m_s']
    )
    # without drag the body keeps more speed
    assert (
        by_name['escape/soft/without'].metrics['distance_m']
        > by_name['escape/soft/with'].metrics['distance_m']
    )
    table = write_csv(rows, tmp_path / 'tiny.csv')
    with open(table) as fh:
        lines = list(csv.DictReader(fh))
    assert (
        len(lines) == 5
        and lines[0]['stiffness'] == 'soft'
        and float(lines[0]['peak_speed_m_s']) > 0
    )


@pytest.mark.timeout(180)
def test_cli_runs_on_the_local_process_pool_with_progress_csv_and_plot(tmp_path):
    path = tmp_path / 'two.yaml'
    path.write_text(SWEEP.replace('duration_s: 2.0', 'duration_s: 0.5').split('  cycle:')[0])
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.cli',
            'sweep',
            str(path),
            '--workers',
            '2',
            '--out',
            str(tmp_path / 'out'),
        ],
        capture_output=True,
        text=True,
        timeout=170,
    )
    assert proc.returncode == 0, proc.stderr
    assert (
        '4/4 runs' in proc.stderr and '\r' not in proc.stderr
    )  # a log gets lines, not carriage returns
    assert (tmp_path / 'out' / 'tiny.csv').read_text().count('\n') == 5
    assert (tmp_path / 'out' / 'tiny.png').read_bytes()[:4] == b'\x89PNG'


def test_bad_sweep_files_are_refused(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('name: x\nmetric: speediness\nstudies: {a: {base: escape}}\n')
    with pytest.raises(SweepError, match="metric: 'speediness'.*allowed"):
        load_sweep(path)
    path.write_text('name: x\nstudies: {a: {axes: {}}}\n')
    with pytest.raises(SweepError, match='studies.a'):
        load_sweep(path)
    with pytest.raises(SweepError, match='not found'):
        load_sweep(tmp_path / 'missing.yaml')
