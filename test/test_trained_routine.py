"""
The trained routine swims as far live as offline, within 2 %.

The routine trained by examples/train_routine.py (stored in examples/results/) runs through the
real controller_node against the real sim_node over ROS (DDS, own domain, localhost discovery),
recorded to MCAP and read back with rosbags: its live distance matches the offline one within 2 %.

sim_node runs in lockstep (`pacing: lockstep`, 100 physics steps = one 10 ms publication batch per
pulsejet/step call) and controller_node at 100 Hz of simulated time, so each command is computed
from the same simulated time as offline; the test steps only after controller_node's command for
the new time was seen on the wire.
"""

from __future__ import annotations

from pathlib import Path

from conftest import isolate_ros
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from pulsejet_sim.routines import PumpValveRoutine  # noqa: E402, I100
from pulsejet_sim.studies.optimize import routine_run  # noqa: E402
from pulsejet_sim.studies.resim import read_applied_commands  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402

RESULTS = Path(__file__).resolve().parent.parent / 'examples' / 'results'
DOMAIN_OFFSET = 61
LIVE_S = 4.0  # simulated seconds of the live run (the stored training used 8 s)
BATCH_S = 0.01
TOPICS = [
    'pulsejet/velocity',
    'pulsejet/volume',
    'pulsejet/energy_ledger',
    'pulsejet/applied_command',
    '/clock',
    'pulsejet/cmd/pump_flow',
    'pulsejet/cmd/valve',
]


@pytest.fixture(scope='module')
def stored():
    summary = yaml.safe_load((RESULTS / 'train_routine.yaml').read_text())
    return summary, RESULTS / summary['trained_scene']


def test_stored_training_beats_the_scene_routine_and_reruns_offline(stored):
    summary, scene = stored
    trained, own = summary['trained'], summary['scene_routine']
    assert summary['feasible'] and trained['distance_m'] >= summary['min_distance_m'] > 0
    assert trained['cost_of_transport'] < own['cost_of_transport']
    again = routine_run(str(scene), None, summary['duration_s'])
    for key in ('distance_m', 'work_j', 'cost_of_transport'):
        assert again[key] == pytest.approx(trained[key], rel=1e-9), key
    assert yaml.safe_load(scene.read_text())['routine'] == summary['trained_routine']


def read_bag(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages(connections=reader.connections):
            out.setdefault(conn.topic.lstrip('/'), []).append(
                reader.deserialize(raw, conn.msgtype)
            )
    return out


@pytest.mark.timeout(150)
def test_trained_routine_over_ros_matches_offline(stored, tmp_path, monkeypatch):
    from pulsejet_sim.ros.harness import SimHarness
    from pulsejet_sim.ros.recorder import Recorder
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger

    summary, scene = stored
    domain = isolate_ros(monkeypatch, DOMAIN_OFFSET)
    mcap = tmp_path / 'trained.mcap'
    steps = int(round(LIVE_S / BATCH_S))
    with SimHarness(
        scene=str(scene),
        controller=True,
        pacing='lockstep',
        domain_id=domain,
        log_dir=tmp_path,
        parameters={'step_count': 100},
        controller_parameters={'rate_hz': 100.0},
    ) as h:
        commands = []
        listener = h.node.create_subscription(
            Float64,
            'pulsejet/cmd/pump_flow',
            lambda m: commands.append(m.data),
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
        )
        recorder = Recorder(h.node, mcap, TOPICS)
        try:
            h.spin_until(
                lambda: len(recorder.subscriptions) == len(TOPICS)
                and all(sub.get_publisher_count() > 0 for sub in recorder.subscriptions.values()),
                30.0,
                'the recorder to match its topics',
            )
            # matched with controller_node's publisher (and the harness's own) before the first
            # step
            h.spin_until(
                lambda: listener.get_publisher_count() >= 2,
                10.0,
                "controller_node's command publisher",
            )
            h.spin(0.2)
            for k in range(steps):
                seen = len(commands)
                response = h.call('step', Trigger.Request())
                assert response.success, response.message
                # controller_node's command for the new time, before the next step
                h.spin_until(lambda: len(commands) > seen, 10.0, f'the command after step {k + 1}')
            h.spin(0.3)
        finally:
            recorder.close()
        assert h.processes['controller_node'].alive(), h.output('controller_node')[-2000:]
    bag = read_bag(mcap)
    velocity = {}
    for msg in bag['pulsejet/velocity']:
        velocity[round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, 6)] = (
            msg.twist.linear.x
        )
    assert max(velocity) == pytest.approx(LIVE_S)
    assert sorted(velocity) == pytest.approx(
        [round(i * BATCH_S, 6) for i in range(min(velocity) > 0, steps + 1)]
    )
    live = sum(v for t, v in velocity.items() if t > 0) * BATCH_S
    offline = routine_run(str(scene), None, LIVE_S)
    assert offline['distance_m'] > 0.5  # it swims: a relative check means something
    assert live == pytest.approx(offline['distance_m'], rel=0.02), (live, offline['distance_m'])
    # the commands sim_node applied are the trained routine's, at the same simulated times
    routine = PumpValveRoutine.from_config(summary['trained_routine'])
    # each applied command holds from its stamp on: of several at one stamp (the scene's initial
    # command at t=0, then the controller's answer for t=0) the last one is the one stepped with
    held = dict(read_applied_commands(mcap))
    assert len(held) >= 3
    for t, values in held.items():
        if t >= LIVE_S - 1e-9:
            continue
        expected = PumpValveRoutine.from_config(summary['trained_routine'])
        for i in range(int(round(t / BATCH_S)) + 1):
            cmd = expected.command(i * BATCH_S)
        assert values.pump_flow_m3_s == pytest.approx(cmd.pump_flow_m3_s), t
        assert values.valve_opening == pytest.approx(cmd.valve_opening), t
    print(
        f'live {live:.6f} m, offline {offline["distance_m"]:.6f} m '
        f'({(live / offline["distance_m"] - 1) * 100:+.4f} %), {len(held)} applied commands'
    )
    assert routine.period_s > 0
