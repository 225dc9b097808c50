"""
The repository builds with `colcon build` and the installed node runs.

It builds as a ROS 2 ament_python package.

Uses colcon-core + colcon-ros from the venv (no system ROS). The repository is copied into
<tmp>/src/pulsejet_sim (without .venv, build, install, log, runs, .git) so the build leaves the
working tree untouched.  The build also warms numba's compile cache for the installed kernels
(setup.py, pulsejet_sim/engine/warmup.py): the installed node must load every kernel from that
cache and compile nothing (checked from numba's NUMBA_DEBUG_CACHE output, not from wall-clock
time).
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import time

from pulsejet_sim.ros.launching import isolated_environment, pick_domain_id
import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'pulsejet_sim'
EXCLUDE = (
    '.venv',
    'venv',
    'build',
    'install',
    'log',
    'runs',
    '.git',
    '__pycache__',
    '*.egg-info',
    '.pytest_cache',
    '*.mcap',
    '*.png',
)


def colcon_command() -> list[str]:
    exe = Path(sys.executable).parent / 'colcon'
    if exe.exists():
        return [str(exe)]
    return [sys.executable, '-m', 'colcon']


def ros_env(offset: int) -> dict:
    env = isolated_environment(pick_domain_id(offset))
    # the build must not see the editable install's source tree through a stale PYTHONPATH
    env.pop('PYTHONPATH', None)
    env.pop('AMENT_PREFIX_PATH', None)
    env.pop('COLCON_PREFIX_PATH', None)
    # numba's cache goes next to the installed kernels (not to a developer's NUMBA_CACHE_DIR)
    env.pop('NUMBA_CACHE_DIR', None)
    env.pop('NUMBA_DISABLE_JIT', None)
    env.pop('PULSEJET_SKIP_NUMBA_WARMUP', None)
    return env


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    ws = tmp_path_factory.mktemp('colcon_ws')
    shutil.copytree(
        REPO, ws / 'src' / PACKAGE, ignore=shutil.ignore_patterns(*EXCLUDE), symlinks=False
    )
    env = ros_env(71)
    # the build compiles the shipped scenes' kernels (~30 s of one core; more on a loaded machine)
    proc = subprocess.run(
        colcon_command() + ['build', '--event-handlers', 'console_direct+'],
        cwd=ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=840,
    )
    assert (
        proc.returncode == 0
    ), f'colcon build failed ({proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}'
    (ws / 'build_output.log').write_text(proc.stdout + proc.stderr)
    return ws


@pytest.mark.timeout(900)
def test_colcon_identifies_ament_python_package(workspace):
    log = (workspace / 'log' / 'latest_build' / 'logger_all.log').read_text()
    assert (
        f"with type 'ros.ament_python' and name '{PACKAGE}'" in log
    ), 'colcon did not identify the package as ros.ament_python:\n' + '\n'.join(
        line for line in log.splitlines() if 'package_identification' in line and PACKAGE in line
    )
    assert "build type 'ament_python'" in log


@pytest.mark.timeout(900)
def test_installed_layout(workspace):
    prefix = workspace / 'install' / PACKAGE
    for exe in ('sim_node', 'controller_node', 'recorder'):
        path = prefix / 'lib' / PACKAGE / exe
        assert path.is_file(), f'{path} missing'
        assert os.access(path, os.X_OK), f'{path} is not executable'
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    assert (prefix / 'share' / PACKAGE / 'package.xml').is_file()
    site = list((prefix / 'lib').glob('python3*/site-packages'))
    assert site, 'no site-packages in the install prefix'
    assert (site[0] / 'pulsejet_sim' / 'ros' / 'sim_node.py').is_file()
    assert (site[0] / 'pulsejet_ctrl' / 'controller_node.py').is_file()


def sourced(workspace: Path, command: str) -> list[str]:
    """Run command in sh after sourcing install/setup.sh (what a user does before `ros2 run`)."""
    return ['sh', '-c', f'. "{workspace}/install/setup.sh" && {command}']


@pytest.mark.timeout(900)
def test_installed_sim_node_runs(workspace):
    env = ros_env(71)
    prefix = workspace / 'install' / PACKAGE
    # the installed copy is imported, not the editable source tree
    where = subprocess.run(
        sourced(
            workspace,
            f'"{sys.executable}" -c "import pulsejet_sim.ros.sim_node as m; print(m.__file__)"',
        ),
        env=env,
        cwd=workspace,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert where.returncode == 0, where.stderr
    assert (
        str(prefix) in where.stdout
    ), f'imported {where.stdout.strip()} instead of the installed copy'

    exe = prefix / 'lib' / PACKAGE / 'sim_node'
    proc = subprocess.Popen(
        sourced(workspace, f'exec "{exe}" --ros-args -p duration_s:=0.5 -p real_time_factor:=2.0'),
        env=env,
        cwd=workspace,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert (
        proc.returncode == 0
    ), f'installed sim_node exited with {proc.returncode}:\n{out[-4000:]}'
    assert 'duration 0.5 s of simulated time reached' in out, out[-4000:]


def site_packages(workspace: Path) -> Path:
    site = list((workspace / 'install' / PACKAGE / 'lib').glob('python3*/site-packages'))
    assert site, 'no site-packages in the install prefix'
    return site[0]


@pytest.mark.timeout(900)
def test_build_warms_numba_cache_of_installed_kernels(workspace):
    out = (workspace / 'build_output.log').read_text()
    assert re.search(
        r'pulsejet_sim: numba compile cache: (\d+)/\1 scenes warmed', out
    ), 'setup.py did not report a warmed numba cache:\n' + '\n'.join(
        line for line in out.splitlines() if 'numba' in line or 'warm' in line
    )
    for model in ('lumped', 'shell'):
        cache = site_packages(workspace) / PACKAGE / 'models' / model / '__pycache__'
        index = list(cache.glob('kernels.advance-*.nbi'))
        data = list(cache.glob('kernels.advance-*.nbc'))
        found = ', '.join(sorted(p.name for p in cache.glob('*.nb?')))
        assert index and data, f'no numba cache of {model}.kernels.advance in {cache}: {found}'
    # recorded as installed files, so colcon removes them with the rest (switch to
    # --symlink-install)
    record = (workspace / 'build' / PACKAGE / 'install.log').read_text().splitlines()
    assert any(
        line.endswith('.nbi') and 'shell/__pycache__/kernels.advance' in line for line in record
    ), 'the numba cache files are not in the install record'


@pytest.mark.timeout(900)
@pytest.mark.parametrize('scene', ['pump_cycle', 'shell_robot'])
def test_installed_sim_node_first_state_from_warm_cache(workspace, scene):
    """
    The installed sim_node loads every kernel from the build-time cache.

    The installed sim_node publishes its first state having loaded every kernel from the cache
    written at build time: NUMBA_DEBUG_CACHE shows data loaded from the installed tree and nothing
    saved.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    env = ros_env(71)
    env['NUMBA_DEBUG_CACHE'] = '1'
    domain = int(env['ROS_DOMAIN_ID'])
    context = rclpy.Context()
    rclpy.init(
        context=context,
        domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('first_state_probe', context=context)
    received = []
    node.create_subscription(
        Clock,
        '/clock',
        received.append,
        QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT),
    )
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    exe = workspace / 'install' / PACKAGE / 'lib' / PACKAGE / 'sim_node'
    proc = subprocess.Popen(
        sourced(workspace, f'exec "{exe}" --ros-args -p scene:={scene}'),
        env=env,
        cwd=workspace,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        end = time.monotonic() + 240
        while not received and proc.poll() is None and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, _ = proc.communicate()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert (
        received
    ), f'no state on /clock from the installed sim_node (scene {scene}):\n{out[-4000:]}'
    model = 'lumped' if scene == 'pump_cycle' else 'shell'
    site = str(site_packages(workspace) / PACKAGE / 'models' / model / '__pycache__')
    module = 'kernels'
    loaded = [
        line
        for line in out.splitlines()
        if line.startswith('[cache] data loaded from') and site in line
    ]
    assert any(
        f'{module}.advance' in line for line in loaded
    ), f'sim_node did not load {module}.advance from the installed cache {site}:\n{out[-4000:]}'
    saved = [line for line in out.splitlines() if line.startswith('[cache] data saved')]
    assert not saved, 'sim_node compiled kernels the build did not warm:\n' + '\n'.join(saved)
