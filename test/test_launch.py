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
import time

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


def calls_of(name: str):
    """Every call of `name` in the launch file."""
    for call in ast.walk(ast.parse(LAUNCH.read_text())):
        if isinstance(call, ast.Call) and getattr(call.func, 'id', None) == name:
            yield call


def first_argument(call) -> str:
    assert call.args and isinstance(call.args[0], ast.Constant), ast.dump(call)
    return call.args[0].value


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
        block = params['/**/' + node['name']]['ros__parameters']
        assert set(block) <= declared[node['name']], set(block) - declared[node['name']]
    # keyed /**/<name>: rcl applies a block keyed by the bare name only to /<name>, never under a
    # namespace
    assert all(key.startswith('/**/') for key in params), sorted(params)
    for name, value in params['/**/sim_node']['ros__parameters'].items():
        sim_node_params.PARAMETER_SPECS[name].check(value)  # in range, the right type
    # the arguments a user drives, each one used, and nothing used that is not declared
    declared_args = {first_argument(c) for c in calls_of('DeclareLaunchArgument')}
    assert declared_args == {
        'namespace', 'params_file', 'scene', 'use_sim_time', 'record', 'output'
    }, declared_args
    assert {first_argument(c) for c in calls_of('LaunchConfiguration')} == declared_args
    record = next(c for c in calls_of('DeclareLaunchArgument') if first_argument(c) == 'record')
    choices = next(kw.value for kw in record.keywords if kw.arg == 'choices')
    assert [e.value for e in choices.elts] == ['true', 'false']
    # every parameter the launch file sets over the params file is one a node declares
    given = {
        key.value
        for d in ast.walk(ast.parse(LAUNCH.read_text()))
        if isinstance(d, ast.Dict)
        for key in d.keys
    }
    assert given == {'scene', 'wait_for_topics', 'use_sim_time', 'output'}, given
    assert given <= set().union(*declared.values()) | {'use_sim_time'}
    text = LAUNCH.read_text()
    assert "{'wait_for_topics': ['*']}" in text  # a recording holds t = 0 on every topic
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


@pytest.mark.timeout(150)
def test_the_params_file_applies_under_a_namespace(monkeypatch):
    """
    The shipped file under `-r __ns:=/robot1`: the live node reports its watchdog.

    watchdog_timeout_s is 0 by default and 0.5 in the file, read back from /robot1/sim_node through
    the real GetParameters service.
    """
    rclpy = pytest.importorskip('rclpy')
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor

    assert sim_node_params.PARAMETER_SPECS['watchdog_timeout_s'].default == 0.0
    domain = isolate_ros(monkeypatch, 64)
    proc = subprocess.Popen(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.ros.sim_node',
            '--ros-args',
            '--params-file',
            str(PARAMS),
            '-p',
            'scene:=pump_cycle',
            '-r',
            '__ns:=/robot1',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    context = rclpy.Context()
    rclpy.init(
        context=context, domain_id=domain,
        signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
    )
    node = rclpy.create_node('params_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        client = node.create_client(GetParameters, '/robot1/sim_node/get_parameters')
        end = time.monotonic() + 100
        while time.monotonic() < end and not client.service_is_ready():
            executor.spin_once(timeout_sec=0.05)
        assert client.service_is_ready(), 'no /robot1/sim_node/get_parameters'
        future = client.call_async(
            GetParameters.Request(names=['watchdog_timeout_s', 'watchdog_action'])
        )
        executor.spin_until_future_complete(future, timeout_sec=10.0)
        timeout, action = future.result().values
        assert (timeout.type, timeout.double_value) == (ParameterType.PARAMETER_DOUBLE, 0.5)
        assert action.string_value == 'safe'
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out[-2000:]
    assert 'watchdog 0.5 s of sim time (safe)' in out, out[-2000:]
