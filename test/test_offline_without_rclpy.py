"""
The offline tools work where rclpy and the ROS message packages cannot be imported.

docs/dev/architecture.md promises that `pulsejet run|summary|plot|animate|sweep|fit|optimize|resim|
repair|view` need no rclpy (a machine with only the PyPI wheels of numpy, mcap and rosbags, a Dask
worker, CI without ROS). Each sub-command runs here in a subprocess whose interpreter refuses
rclpy, rcl*, rmw*, rosidl* and every *_msgs / *_interfaces / *_srvs package: a sitecustomize on
PYTHONPATH inserts a meta-path finder that raises ImportError for them, in the process and in the
worker processes it starts. The .msg definitions the writer stores come from the packages' share
directories, which stay (they are files, not Python).
"""

import os
from pathlib import Path
import subprocess
import sys
import textwrap

import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
import yaml

REPO = Path(__file__).resolve().parent.parent

BLOCKER = textwrap.dedent(
    '''
    """Test shim: ROS Python packages cannot be imported in this interpreter."""
    import importlib.abc
    import sys

    PREFIXES = ('rclpy', 'rcl_', 'rcutils', 'rmw', 'rosidl', 'rpyutils')
    SUFFIXES = ('_msgs', '_interfaces', '_srvs')


    class NoRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            top = name.partition('.')[0]
            if top.startswith(PREFIXES) or top.endswith(SUFFIXES):
                raise ImportError(f'{name} is blocked: an offline tool imported ROS', name=name)
            return None


    sys.meta_path.insert(0, NoRos())
    '''
)


@pytest.fixture(scope='module')
def without_ros(tmp_path_factory):
    """Run `pulsejet ARGS` (cwd = a scratch folder) where rclpy is unimportable."""
    shim = tmp_path_factory.mktemp('no_ros_shim')
    (shim / 'sitecustomize.py').write_text(BLOCKER)
    work = tmp_path_factory.mktemp('offline')
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(shim), str(REPO)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    )
    env['MPLBACKEND'] = 'Agg'

    def run(*args, timeout=240, code=None):
        cmd = [sys.executable, '-c', code] if code else [
            sys.executable, '-m', 'pulsejet_sim.cli', *args
        ]
        proc = subprocess.run(
            cmd, cwd=work, env=env, capture_output=True, text=True, timeout=timeout
        )
        assert 'is blocked: an offline tool imported ROS' not in proc.stderr, proc.stderr[-3000:]
        return proc

    run.work = work
    run.shim = shim
    return run


def test_the_shim_blocks_rclpy_and_message_packages(without_ros):
    for module in ('rclpy', 'std_msgs.msg', 'builtin_interfaces.msg', 'rosidl_runtime_py'):
        proc = subprocess.run(
            [sys.executable, '-c', f'import {module}'],
            env=dict(os.environ, PYTHONPATH=str(without_ros.shim)),
            capture_output=True, text=True, timeout=120,
        )
        assert proc.returncode != 0 and 'is blocked' in proc.stderr, (module, proc.stderr)


@pytest.mark.timeout(900)
def test_every_offline_subcommand_runs_without_rclpy(without_ros):
    work = without_ros.work

    def ok(*args, **kw):
        proc = without_ros(*args, **kw)
        assert proc.returncode == 0, (args, proc.stderr[-3000:])
        return proc

    # run (with its summary and plot), a lumped and a shell scene
    proc = ok('run', 'pump_cycle', '--duration', '1.5', '--out', 'cycle.mcap')
    assert 'peak speed' in proc.stdout and (work / 'cycle.png').read_bytes()[:4] == b'\x89PNG'
    ok('run', 'shell_robot', '--duration', '0.3', '--out', 'shell.mcap', '--no-plot')
    with AnyReader(
        [work / 'cycle.mcap'], default_typestore=get_typestore(Stores.ROS2_JAZZY)
    ) as reader:
        assert {c.topic for c in reader.connections} >= {'/pulsejet/velocity', '/odom', '/clock'}
        assert sum(1 for _ in reader.messages()) > 150 * 10
    # read-back tools
    assert 'thrust impulse' in ok('summary', 'cycle.mcap').stdout
    ok('plot', 'cycle.mcap', '--out', 'cycle2.png')
    assert (work / 'cycle2.png').read_bytes()[:4] == b'\x89PNG'
    ok('animate', 'shell.mcap', '-o', 'shell.gif', '--fps', '10', '--stride', '7')
    assert (work / 'shell.gif').read_bytes()[:3] == b'GIF'
    # resim, writing its own recording
    ok('resim', 'cycle.mcap', '--out', 'again.mcap')
    assert (work / 'again.mcap').stat().st_size > 0
    # repair a recording cut short
    data = (work / 'cycle.mcap').read_bytes()
    (work / 'cut.mcap').write_bytes(data[: len(data) * 2 // 3])
    ok('repair', 'cut.mcap')
    assert (work / 'cut.repaired.mcap').exists()
    # sweep on worker processes (they start with the same shim)
    (work / 'tiny.yaml').write_text(
        'name: tiny\nduration_s: 0.3\nmetric: peak_speed_m_s\nstudies:\n  escape:\n'
        '    base: escape\n    axes:\n      stiffness:\n'
        '        soft: {material: {stiffness_n_m: 1000}}\n'
        '        stiff: {material: {stiffness_n_m: 4000}}\n'
    )
    ok('sweep', 'tiny.yaml', '--workers', '2', '--out', 'sweep')
    assert (work / 'sweep' / 'tiny.csv').read_text().count('\n') == 3
    # fit to the recording made above
    (work / 'fit.yaml').write_text(
        yaml.safe_dump(
            {
                'scene': 'pump_cycle',
                'parameters': {
                    'material.stiffness_n_m': {'low': 500.0, 'high': 5000.0, 'initial': 2500.0}
                },
                'recording': {'file': 'cycle.mcap'},
            },
            sort_keys=False,
        )
    )
    ok('fit', 'fit.yaml', '--max-evals', '2', '--out', 'fit', '--quiet')
    assert any((work / 'fit').iterdir())
    # optimize on a worker process
    (work / 'opt.yaml').write_text(
        'name: escape_small\nscene: escape\nduration_s: 0.3\n'
        'objective: {metric: peak_speed_m_s, sense: max}\n'
        'parameters:\n  material.stiffness_n_m: {low: 1000, high: 4000, scale: log}\n'
        'options: {max_evals: 4, population: 4, seed: 3}\n'
    )
    ok('optimize', 'opt.yaml', '--workers', '1', '--out', 'opt')
    assert any((work / 'opt').iterdir())


def test_live_view_serves_without_rclpy(without_ros):
    """`pulsejet view` (Foxglove WebSocket, pulsejet_sim.view) runs and stops without ROS."""
    proc = without_ros(
        'view', 'shell_robot', '--duration', '0.3', '--port', '0', '--real-time-factor', '3'
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert 'ws://127.0.0.1:' in proc.stdout and '0.3 s simulated; done' in proc.stdout
