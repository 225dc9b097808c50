"""
End to end: sim_node + controller_node processes, recorded to MCAP.

Every topic is recorded to MCAP and read back with rosbags.

Runs in a ROS domain derived from the pytest pid with localhost-only discovery; a short simulated
duration at real_time_factor > 1 keeps it well under a minute.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from conftest import isolate_ros
import numpy as np
from pulsejet_sim.ros.launching import isolated_environment, pick_domain_id
import pytest

rclpy = pytest.importorskip('rclpy')
from rosbags.highlevel import AnyReader  # noqa: E402

DOMAIN_OFFSET = 37
DURATION_S = 6.0  # pump_cycle: inflate 2 s, hold 0.2 s, jet 1.8 s -> 1.5 cycles
REAL_TIME_FACTOR = 3.0


@pytest.fixture
def ros_domain(monkeypatch):
    return isolate_ros(monkeypatch, DOMAIN_OFFSET)


def read_bag(path: Path) -> dict[str, list[tuple[float, object]]]:
    """Read a recording with rosbags: topic -> [(header/clock stamp in s or None, message)]."""
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages(connections=reader.connections):
            msg = reader.deserialize(raw, conn.msgtype)
            if hasattr(msg, 'header'):
                t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            elif hasattr(msg, 'clock'):
                t = msg.clock.sec + msg.clock.nanosec * 1e-9
            else:
                t = None
            out.setdefault(conn.topic, []).append((t, msg))
    return out


def values_of(entries) -> list[float]:
    return [m.data for _, m in entries]


@pytest.mark.timeout(150)
def test_sim_and_controller_swim_recorded_to_mcap(tmp_path):
    from pulsejet_sim.core import topics as names
    from pulsejet_sim.ros.harness import SimHarness
    from pulsejet_sim.ros.recorder import Recorder

    mcap = tmp_path / 'run.mcap'
    t_start = time.monotonic()
    # start paused: the recorder subscribes, then the run starts from t=0 with everything matched
    with SimHarness(
        scene='pump_cycle',
        controller=True,
        log_dir=tmp_path,
        parameters={
            'duration_s': DURATION_S,
            'real_time_factor': REAL_TIME_FACTOR,
            'start_paused': True,
        },
    ) as h:
        recorder = Recorder(h.node, mcap, None)
        try:
            # every topic but the mantle profile (a shell-model topic; pump_cycle is lumped) and
            # the atomic command (sent by closed-loop controllers only)
            expected = [
                t if t.startswith('/') else '/' + t
                for t in names.TOPIC_TYPES
                if not t.endswith(('mantle_profile', 'cmd/command'))
            ]
            h.spin_until(
                lambda: all(
                    t in recorder.subscriptions
                    and recorder.subscriptions[t].get_publisher_count() > 0
                    for t in expected
                ),
                30.0,
                'the recorder to match every topic',
            )
            assert h.resume().success
            assert h.wait_for_exit('sim_node', timeout_s=100) == 0, h.output()[-3000:]
            # sim_node exits once every reliable subscriber acknowledged its samples; take them
            # all: the final state on every state topic (not a fixed wait, which load can beat)
            state_topics = [f'/{t}' for t in names.STATE_TOPICS if t != names.TOPIC_CLOCK]

            def whole_recording() -> bool:
                counts = [recorder.message_counts.get(t, 0) for t in state_topics]
                return abs(h.time_s - DURATION_S) < 1e-9 and len(set(counts)) == 1

            h.spin_until(
                whole_recording, 60.0, 'the recorder to take every state', check_alive=False
            )
            assert h.processes['controller_node'].alive(), h.output('controller_node')[-3000:]
        finally:
            recorder.close()
        sim_log = h.output()
    codes = h.exit_codes
    wall = time.monotonic() - t_start
    assert codes['sim_node'] == 0, f'sim_node exit {codes["sim_node"]}:\n{sim_log[-3000:]}'
    assert codes['controller_node'] == 0, (tmp_path / 'controller_node.log').read_text()[-3000:]
    assert 'ERROR' not in sim_log, sim_log[-3000:]
    print(f'wall time {wall:.1f} s for {DURATION_S} s simulated at rtf {REAL_TIME_FACTOR}')

    bag = read_bag(mcap)
    for topic in (
        '/clock',
        '/pulsejet/volume',
        '/pulsejet/velocity',
        '/pulsejet/thrust',
        '/pulsejet/mantle_radius',
        '/pulsejet/fluid_mass',
        '/pulsejet/energy_ledger',
        '/pulsejet/cmd/pump_flow',
        '/pulsejet/cmd/valve',
        '/pulsejet/cmd/cable_force',
        '/pulsejet/applied_command',
    ):
        assert bag.get(topic), f'{topic} not recorded; have {sorted(bag)}'

    # nothing is NaN
    for topic in (
        '/pulsejet/volume',
        '/pulsejet/mantle_radius',
        '/pulsejet/fluid_mass',
        '/pulsejet/cmd/pump_flow',
        '/pulsejet/cmd/valve',
        '/pulsejet/cmd/cable_force',
    ):
        assert all(math.isfinite(v) for v in values_of(bag[topic])), topic
    velocity = np.array([(t, m.twist.linear.x) for t, m in bag['/pulsejet/velocity']])
    thrust = np.array([(t, m.wrench.force.x) for t, m in bag['/pulsejet/thrust']])
    assert np.isfinite(velocity).all() and np.isfinite(thrust).all()
    for _, m in bag['/pulsejet/energy_ledger']:
        assert all(math.isfinite(float(kv.value)) for kv in m.status[0].values)

    # simulation time: stamps from 0 to the duration, the clock reached the duration
    clock = np.array([t for t, _ in bag['/clock']])
    assert clock.min() >= 0 and abs(clock.max() - DURATION_S) < 1e-6, (clock.min(), clock.max())
    back = np.flatnonzero(np.diff(clock) < 0)
    assert back.size == 0, [tuple(clock[max(0, i - 2):i + 3]) for i in back[:5]]
    assert abs(velocity[:, 0].max() - DURATION_S) < 1e-9, 'the final state was not recorded'

    # the controller cycled the pump and the valve
    pump = values_of(bag['/pulsejet/cmd/pump_flow'])
    valve = values_of(bag['/pulsejet/cmd/valve'])
    assert max(pump) > 0 and min(pump) == 0.0
    assert max(valve) > 0.5 and min(valve) == 0.0

    # the volume rose and fell at least once
    vol = np.array(values_of(bag['/pulsejet/volume']), dtype=float)  # in publication order
    v0, v_max = vol[0], vol.max()
    assert v_max > 1.5 * v0, f'volume did not rise: start {v0:.3e}, max {v_max:.3e} m^3'
    high, low = v0 + 0.75 * (v_max - v0), v0 + 0.25 * (v_max - v0)
    i_high = int(np.argmax(vol > high))
    assert (
        vol[i_high:].min() < low
    ), f'volume did not fall after rising: max {v_max:.3e}, min after {vol[i_high:].min():.3e} m^3'

    # the applied commands replay the run offline step for step (same kernels, same batches'
    # commands)
    applied = bag.get('/pulsejet/applied_command')
    assert applied, 'no /pulsejet/applied_command recorded'
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.ros.messages import command_from_applied
    from pulsejet_sim.scene import load_scene

    changes = sorted((command_from_applied(m) for _, m in applied), key=lambda tc: tc[0])  # stable
    replay = Simulation(load_scene('pump_cycle').model)
    dt = replay.model.dt_s
    held = replay.command  # the scene's initial command until the first applied one
    for t_i, cmd in changes + [(DURATION_S, None)]:
        n = int(round(t_i / dt)) - replay.steps
        assert n >= 0
        if n:
            replay.step(n, held)
        held = cmd
    final = replay.observe()
    assert abs(final.time_s - DURATION_S) < 1e-9
    recorded_u = velocity[np.argmax(velocity[:, 0]), 1]
    recorded_v = vol[-1]
    # every recorded state, not only the last: a divergence is named with its time
    from pulsejet_sim.studies.resim import resimulate

    every_state = resimulate(mcap, scene='pump_cycle')
    assert every_state.bit_identical, every_state.format_table()
    assert final.velocity_m_s == pytest.approx(recorded_u, rel=1e-9, abs=1e-12)
    assert final.volume_m3 == pytest.approx(recorded_v, rel=1e-9, abs=1e-15)

    # the vehicle swam forward
    order = np.argsort(velocity[:, 0])
    t, u = velocity[order, 0], velocity[order, 1]
    distance = float(np.sum(0.5 * (u[1:] + u[:-1]) * np.diff(t)))
    assert distance > 0.05, f'distance {distance:.4f} m'
    assert u.max() > 0.05


@pytest.mark.timeout(150)
def test_demo_end_to_end(ros_domain, tmp_path):
    """`python -m pulsejet_sim.ros.demo`: processes, recording, summary and plot, exit 0."""
    out = tmp_path / 'demo.mcap'
    env = isolated_environment(pick_domain_id(DOMAIN_OFFSET + 1))
    proc = subprocess.Popen(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.ros.demo',
            '--duration',
            '3',
            '--real-time-factor',
            '3',
            '--out',
            str(out),
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        start_new_session=True,
    )
    try:
        text, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert proc.returncode == 0, text[-4000:]
    assert out.is_file() and out.stat().st_size > 0
    png = out.with_suffix('.png')
    assert png.is_file(), text[-2000:]
    assert f'recording: {out}' in text and f'plot:      {png}' in text, text[-2000:]
    assert 'distance' in text, text[-2000:]
    assert "scene 'shell_robot'" in text and '/pulsejet/mantle_profile' in text, text[
        -2000:
    ]  # the default scene


@pytest.mark.timeout(60)
def test_demo_reports_a_failing_child(ros_domain, tmp_path):
    """
    A sim_node that cannot start (unknown scene) makes the demo exit non-zero.

    The demo reports the reason.
    """
    out = tmp_path / 'bad.mcap'
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'pulsejet_sim.ros.demo',
            '--duration',
            '1',
            '--scene',
            'no_such_scene',
            '--out',
            str(out),
        ],
        env=dict(os.environ),
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=50,
    )
    assert proc.returncode != 0
    assert 'demo failed' in proc.stderr and 'no_such_scene' in proc.stderr, proc.stderr[-3000:]
