"""
The launch file (launch/pulsejet.launch.py), checked without `launch`.

The launch file (launch/pulsejet.launch.py), checked without `launch` (not installable here):
every executable it starts exists, every parameter in its params file is declared by that node, the
files it names are installed by setup.py, and sim_node accepts the params file for real.
"""

import ast
from pathlib import Path
import subprocess
import sys

from conftest import isolate_ros
from pulsejet_ctrl import controller_node
from pulsejet_sim.ros import sim_node_params
import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / 'launch' / 'pulsejet.launch.py'
PARAMS = ROOT / 'config' / 'params' / 'pulsejet.yaml'


def launched_nodes():
    tree = ast.parse(LAUNCH.read_text())
    nodes = []
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, 'id', None) == 'Node':
            nodes.append(
                {
                    kw.arg: kw.value.value
                    for kw in call.keywords
                    if isinstance(kw.value, ast.Constant)
                }
            )
    return nodes


def console_scripts():
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and ' = ' in node.value:
            yield node.value.split(' = ')


def test_launch_starts_installed_executables_with_declared_parameters():
    nodes = launched_nodes()
    assert {n['executable'] for n in nodes} == {'sim_node', 'controller_node', 'recorder'}
    scripts = dict(console_scripts())
    declared = {
        'sim_node': set(sim_node_params.PARAMETER_SPECS),
        'controller_node': (
            {'scene', 'rate_hz', 'closed_loop'} | set(controller_node.ROUTINE_FIELDS)
        ),
        'recorder': {'output', 'topics'},
    }
    params = yaml.safe_load(PARAMS.read_text())
    for node in nodes:
        assert node['package'] == 'pulsejet_sim'
        module, function = scripts[node['executable']].split(':')
        assert (ROOT / (module.replace('.', '/') + '.py')).is_file() and function == 'main'
        block = params[node['name']]['ros__parameters']
        assert set(block) <= declared[node['name']], set(block) - declared[node['name']]
    for name, value in params['sim_node']['ros__parameters'].items():
        sim_node_params.PARAMETER_SPECS[name].check(value)  # in range, the right type
    setup = (ROOT / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in setup and "glob('config/params/*.yaml')" in setup
    assert "'config', 'params', 'pulsejet.yaml'" in LAUNCH.read_text()


@pytest.mark.timeout(120)
def test_sim_node_runs_from_the_params_file(monkeypatch):
    isolate_ros(monkeypatch, 63)
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.ros.sim_node',
            '--ros-args',
            '--params-file',
            str(PARAMS),
            '-p',
            'scene:=pump_cycle',
            '-p',
            'duration_s:=0.05',
        ],
        capture_output=True,
        text=True,
        timeout=100,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert 'watchdog 0.5 s of sim time (safe)' in proc.stdout + proc.stderr
