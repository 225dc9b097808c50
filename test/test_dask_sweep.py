"""
`pulsejet sweep` on Dask reproduces the local process pool's CSV row for row.

`pulsejet sweep` on Dask: a real distributed.LocalCluster with worker processes reproduces the
local process pool's CSV row for row.

The CSVs are written with timing=False (`--no-timing`): wall_s is the one column that differs
between two runs of the same sweep; with it left out the files must be byte-identical. The
columns with timing are compared too, all but wall_s.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

from pulsejet_sim.studies.sweep import load_sweep, open_executor, run_sweep, write_csv
import pytest

distributed = pytest.importorskip('distributed')

SWEEP = """
name: dask_check
duration_s: 1.0
metric: peak_speed_m_s
studies:
  escape:
    base: escape
    axes:
      stiffness:
        k1000: {material: {stiffness_n_m: 1000}}
        k2094: {material: {stiffness_n_m: 2094}}
        k4000: {material: {stiffness_n_m: 4000}}
      coupling:
        consistent: {options: {coupling: consistent}}
        paper: {options: {coupling: paper}}
  refused:
    base: escape
    overrides: {material: {stiffness_n_m: -1}}
"""


@pytest.fixture(scope='module')
def cluster():
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0'
    ) as c:
        yield c


@pytest.fixture(scope='module')
def sweep_file(tmp_path_factory):
    path = tmp_path_factory.mktemp('sweep') / 'dask_check.yaml'
    path.write_text(SWEEP)
    return path


@pytest.fixture(scope='module')
def pool_csv(sweep_file, tmp_path_factory):
    _, runs = load_sweep(sweep_file)
    with open_executor(workers=2) as executor:
        rows = run_sweep(runs, executor=executor, progress=None)
    out = tmp_path_factory.mktemp('pool')
    return write_csv(rows, out / 'plain.csv', timing=False), write_csv(rows, out / 'timed.csv')


def rows_without(path: Path, column: str) -> list[list[str]]:
    with open(path, newline='') as fh:
        table = list(csv.reader(fh))
    drop = table[0].index(column)
    return [r[:drop] + r[drop + 1:] for r in table]


@pytest.mark.timeout(120)
def test_local_cluster_reproduces_the_process_pool_csv(cluster, sweep_file, pool_csv, tmp_path):
    with distributed.Client(cluster) as client:
        # the work happens in other processes, one per worker
        pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids
        _, runs = load_sweep(sweep_file)
        rows = run_sweep(runs, executor=client.get_executor(pure=False), progress=None)
    plain = write_csv(rows, tmp_path / 'plain.csv', timing=False)
    timed = write_csv(rows, tmp_path / 'timed.csv')
    pool_plain, pool_timed = pool_csv
    assert plain.read_text() == pool_plain.read_text()
    assert rows_without(timed, 'wall_s') == rows_without(pool_timed, 'wall_s')
    table = list(csv.DictReader(open(plain)))
    assert len(table) == 7 and 'wall_s' not in table[0]
    assert all(
        r['peak_speed_m_s'] for r in table if r['study'] == 'escape'
    )  # real runs, not empty rows
    assert table[-1]['fault'].startswith('refused:') and 'stiffness_n_m' in table[-1]['fault']


@pytest.mark.timeout(120)
def test_cli_sweep_on_a_scheduler_address(cluster, sweep_file, pool_csv, tmp_path, capsys):
    from pulsejet_sim.cli import main

    out = tmp_path / 'cli'
    assert (
        main(
            [
                'sweep',
                str(sweep_file),
                '--scheduler',
                cluster.scheduler_address,
                '--out',
                str(out),
                '--no-timing',
            ]
        )
        == 0
    )
    assert f'the Dask scheduler {cluster.scheduler_address}' in capsys.readouterr().out
    assert (out / 'dask_check.csv').read_text() == pool_csv[0].read_text()
    assert (out / 'dask_check.png').stat().st_size > 0


def test_cli_refuses_both_executors(sweep_file, capsys):
    from pulsejet_sim.cli import main

    assert (
        main(['sweep', str(sweep_file), '--scheduler', 'tcp://127.0.0.1:1', '--dask-workers', '2'])
        == 2
    )
    assert 'exclude each other' in capsys.readouterr().err
    assert main(['sweep', str(sweep_file), '--dask-workers', '0']) == 2
    assert '--dask-workers 0 rejected' in capsys.readouterr().err
