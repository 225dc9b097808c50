"""The offline command: same core and routine as the nodes, no DDS, same topics in MCAP."""

import math
from pathlib import Path
import subprocess
import sys

import numpy as np
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import run_scene
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

REPO = Path(__file__).resolve().parent.parent
PULSEJET = [sys.executable, '-m', 'pulsejet_sim.cli']


def read_all(path):
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        out = {}
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
        types = {c.topic: c.msgtype for c in reader.connections}
    return out, types


@pytest.mark.timeout(120)
def test_pulsejet_run_writes_the_live_topics_and_summary_and_plot_work(tmp_path):
    out = tmp_path / 'cycle.mcap'
    proc = subprocess.run(
        PULSEJET + ['run', 'pump_cycle', '--duration', '6', '--out', str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=110,
    )
    assert proc.returncode == 0, proc.stderr
    assert 'peak speed' in proc.stdout and 'closure_error' in proc.stdout
    msgs, types = read_all(out)
    assert types['/pulsejet/velocity'] == 'geometry_msgs/msg/TwistStamped'
    assert types['/pulsejet/thrust'] == 'geometry_msgs/msg/WrenchStamped'
    assert types['/pulsejet/volume'] == 'std_msgs/msg/Float64'
    assert types['/clock'] == 'rosgraph_msgs/msg/Clock'
    velocity = np.array([m.twist.linear.x for m in msgs['/pulsejet/velocity']])
    volume = np.array([m.data for m in msgs['/pulsejet/volume']])
    stamps = np.array(
        [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in msgs['/pulsejet/velocity']]
    )
    assert len(velocity) == 601 and stamps[-1] == pytest.approx(6.0)
    assert np.all(np.diff(stamps) > 0)
    assert np.all(np.isfinite(velocity)) and np.all(np.isfinite(volume))
    assert velocity.max() > 0.1 and volume.max() > 2.5 * volume.min()  # it pumped, jetted and swam
    pump = [m.data for m in msgs['/pulsejet/cmd/pump_flow']]
    assert max(pump) == pytest.approx(2.5e-3) and min(pump) == 0.0
    summary = subprocess.run(
        PULSEJET + ['summary', str(out)], capture_output=True, text=True, timeout=60
    )
    assert summary.returncode == 0 and 'thrust impulse' in summary.stdout
    png = tmp_path / 'cycle-plot.png'
    plot = subprocess.run(
        PULSEJET + ['plot', str(out), '--out', str(png)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert plot.returncode == 0, plot.stderr
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_pulsejet_run_refuses_a_bad_scene_with_a_clear_message(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text(
        (REPO / 'config' / 'escape.yaml')
        .read_text()
        .replace('stiffness_n_m: 2094', 'stiffness_n_m: -1')
    )
    proc = subprocess.run(
        PULSEJET + ['run', str(bad), '--duration', '1', '--out', str(tmp_path / 'x.mcap')],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert (
        'material.stiffness_n_m' in proc.stderr
        and '-1' in proc.stderr
        and 'allowed' in proc.stderr
    )
    assert 'Traceback' not in proc.stderr
    proc = subprocess.run(
        PULSEJET + ['run', 'nonexistent_scene'], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2 and 'pump_cycle' in proc.stderr


def test_offline_run_is_deterministic_and_matches_direct_stepping(tmp_path):
    scene = load_scene('escape')
    a = run_scene(scene, 1.0, tmp_path / 'a.mcap')
    b = run_scene(load_scene('escape'), 1.0, tmp_path / 'b.mcap')
    assert np.array_equal(a.sim.state, b.sim.state)
    msgs_a, _ = read_all(tmp_path / 'a.mcap')
    msgs_b, _ = read_all(tmp_path / 'b.mcap')
    va = [m.twist.linear.x for m in msgs_a['/pulsejet/velocity']]
    vb = [m.twist.linear.x for m in msgs_b['/pulsejet/velocity']]
    assert va == vb and len(va) == 101
    ledger = msgs_a['/pulsejet/energy_ledger'][-1].status[0]
    values = {kv.key: float(kv.value) for kv in ledger.values}
    assert math.isclose(values['in_initial'], 0.5 * 2094 * (0.1368 - 0.036) ** 2, rel_tol=1e-9)


def test_a_blow_up_ends_the_run_with_the_fault_and_no_nan(tmp_path):
    scene = load_scene(
        'escape', {'options': {'coupling': 'paper'}}
    )  # paper 001 as written: it collapses
    result = run_scene(scene, 5.0, tmp_path / 'boom.mcap')
    assert result.fault and 'minor semi-axis collapsed' in result.fault
    msgs, _ = read_all(tmp_path / 'boom.mcap')
    radius = np.array([m.data for m in msgs['/pulsejet/mantle_radius']])
    assert np.all(np.isfinite(radius)) and len(radius) < 501


def test_shell_cable_from_commands_matches_the_built_in_routine_and_records_the_profile(tmp_path):
    """
    Commands and the model's own routine pull the shell's cable alike.

    Live runs drive the shell's cable by commands (controller_node's CableRoutine); offline runs
    may use the model's own routine. Both pull alike, up to the 100 Hz hold of the command.
    """
    built_in = run_scene(load_scene('shell_robot'), 2.0)
    commanded = run_scene(
        load_scene('shell_robot', command_driven=True), 2.0, tmp_path / 'shell.mcap'
    )
    assert commanded.sim.model.actuation['source'] == 'command'
    assert commanded.sim.observe().velocity_m_s == pytest.approx(
        built_in.sim.observe().velocity_m_s, rel=0.1
    )
    assert commanded.sim.observe().position_m == pytest.approx(
        built_in.sim.observe().position_m, rel=0.1
    )
    msgs, types = read_all(tmp_path / 'shell.mcap')
    assert types['/pulsejet/mantle_profile'] == 'geometry_msgs/msg/PolygonStamped'
    profile = msgs['/pulsejet/mantle_profile'][-1].polygon.points
    r, z = commanded.sim.profile()
    assert (
        len(profile) == len(r)
        and profile[0].y == pytest.approx(r[0])
        and profile[-1].x == pytest.approx(z[-1])
    )
    cable = [m.data for m in msgs['/pulsejet/cmd/cable_force']]
    assert max(cable) == pytest.approx(8.0, rel=0.02) and min(cable) == 0.0


def test_shell_scene_is_deterministic():
    a = run_scene(load_scene('shell_robot'), 0.5)
    b = run_scene(load_scene('shell_robot'), 0.5)
    assert a.sim.steps == b.sim.steps == 50
    assert np.array_equal(a.sim.state, b.sim.state)
    assert a.sim.observe().velocity_m_s > 0.0


def test_cli_lists_every_command_and_refuses_an_unknown_one():
    out = subprocess.run(PULSEJET + ['-h'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    for command in (
        'run',
        'summary',
        'plot',
        'resim',
        'repair',
        'sweep',
        'fit',
        'optimize',
        'scenes',
    ):
        assert f'\n    {command} ' in out.stdout, out.stdout
    bad = subprocess.run(PULSEJET + ['swim'], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "invalid choice: 'swim'" in bad.stderr and "'run'" in bad.stderr
    opts = subprocess.run(PULSEJET + ['run', '-h'], capture_output=True, text=True, timeout=60)
    assert opts.returncode == 0 and '--duration' in opts.stdout and '--dt' in opts.stdout
