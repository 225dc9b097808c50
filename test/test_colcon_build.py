"""The repository builds with `colcon build` as a ROS 2 ament_python package and the installed node runs.

Uses colcon-core + colcon-ros from the venv (no system ROS). The repository is copied into
<tmp>/src/pulsejet_sim (without .venv, build, install, log, runs, .git) so the build leaves the
working tree untouched.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'pulsejet_sim'
EXCLUDE = ('.venv', 'venv', 'build', 'install', 'log', 'runs', '.git', '__pycache__', '*.egg-info',
           '.pytest_cache', '*.mcap', '*.png')


def colcon_command() -> list[str]:
    exe = Path(sys.executable).parent / 'colcon'
    if exe.exists():
        return [str(exe)]
    return [sys.executable, '-m', 'colcon']


def ros_env(offset: int) -> dict:
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(1 + (os.getpid() + offset) % 100)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
    env['RCUTILS_COLORIZED_OUTPUT'] = '0'
    env['PYTHONUNBUFFERED'] = '1'
    # the build must not see the editable install's source tree through a stale PYTHONPATH
    env.pop('PYTHONPATH', None)
    env.pop('AMENT_PREFIX_PATH', None)
    env.pop('COLCON_PREFIX_PATH', None)
    return env


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    ws = tmp_path_factory.mktemp('colcon_ws')
    shutil.copytree(REPO, ws / 'src' / PACKAGE, ignore=shutil.ignore_patterns(*EXCLUDE), symlinks=False)
    env = ros_env(71)
    proc = subprocess.run(colcon_command() + ['build', '--event-handlers', 'console_direct+'],
                          cwd=ws, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f'colcon build failed ({proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}'
    return ws


@pytest.mark.timeout(300)
def test_colcon_identifies_ament_python_package(workspace):
    log = (workspace / 'log' / 'latest_build' / 'logger_all.log').read_text()
    assert f"with type 'ros.ament_python' and name '{PACKAGE}'" in log, \
        'colcon did not identify the package as ros.ament_python:\n' + \
        '\n'.join(line for line in log.splitlines() if 'package_identification' in line and PACKAGE in line)
    assert "build type 'ament_python'" in log


@pytest.mark.timeout(300)
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
    assert (site[0] / 'pulsejet_sim' / 'sim_node.py').is_file()
    assert (site[0] / 'pulsejet_ctrl' / 'controller_node.py').is_file()


def sourced(workspace: Path, command: str) -> list[str]:
    """Run command in sh after sourcing install/setup.sh (what a user does before `ros2 run`)."""
    return ['sh', '-c', f'. "{workspace}/install/setup.sh" && {command}']


@pytest.mark.timeout(300)
def test_installed_sim_node_runs(workspace):
    env = ros_env(71)
    prefix = workspace / 'install' / PACKAGE
    # the installed copy is imported, not the editable source tree
    where = subprocess.run(sourced(workspace, f'"{sys.executable}" -c "import pulsejet_sim.sim_node as m; print(m.__file__)"'),
                           env=env, cwd=workspace, capture_output=True, text=True, timeout=120)
    assert where.returncode == 0, where.stderr
    assert str(prefix) in where.stdout, f'imported {where.stdout.strip()} instead of the installed copy'

    exe = prefix / 'lib' / PACKAGE / 'sim_node'
    proc = subprocess.Popen(
        sourced(workspace, f'exec "{exe}" --ros-args -p duration_s:=0.5 -p real_time_factor:=2.0'),
        env=env, cwd=workspace, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, f'installed sim_node exited with {proc.returncode}:\n{out[-4000:]}'
    assert 'duration 0.5 s of simulated time reached' in out, out[-4000:]
