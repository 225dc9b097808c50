"""
Closed-loop lockstep over real DDS: the same closed loop gives the same run.

Closed-loop lockstep over real DDS: sim_node waits for controller_node's answer to every state,
so the same closed loop gives the same run bit for bit, on an idle machine or a loaded one. The
runs are recorded by the recorder process and read back with rosbags.
"""

import multiprocessing
import signal

from conftest import isolate_ros
from pulsejet_sim.ros.harness import SimHarness
import pytest
from test_recorder import read_all, start_recorder


def burn(stop):
    while not stop.is_set():
        sum(i * i for i in range(10_000))


def closed_loop_run(domain, load: bool, tmp_path):
    tmp_path.mkdir(parents=True, exist_ok=True)
    stop = multiprocessing.Event()
    burners = [
        multiprocessing.Process(target=burn, args=(stop,), daemon=True)
        for _ in range(2 if load else 0)
    ]
    for p in burners:
        p.start()
    recorder, out = start_recorder(tmp_path, domain)
    try:
        with SimHarness(
            scene='pump_cycle',
            controller=True,
            pacing='closed_loop',
            domain_id=domain,
            parameters={
                'duration_s': 1.5,
                'control_period_s': 0.02,
                'publish_rate_hz': 50.0,
                'wait_for_subscribers': 2,
            },  # the harness's and the recorder's /clock
            controller_parameters={'closed_loop': True},
            wait_started=False,
        ) as h:
            h.wait_for_exit('sim_node', 90.0)
            h.spin(0.5)
        recorder.send_signal(signal.SIGINT)
        recorder.communicate(timeout=30)
        found = read_all(out)

        def by_stamp(topic, value):
            return {
                m.header.stamp.sec * 10**9 + m.header.stamp.nanosec: value(m) for m in found[topic]
            }

        states = {
            'velocity': by_stamp('/pulsejet/velocity', lambda m: m.twist.linear.x),
            'thrust': by_stamp('/pulsejet/thrust', lambda m: m.wrench.force.x),
            'ledger': by_stamp(
                '/pulsejet/energy_ledger',
                lambda m: [(kv.key, kv.value) for kv in m.status[0].values],
            ),
            # the command held from each stamp on (the last one published at a stamp; the scene's
            # initial command at t=0 may be published before the recorder has matched the topic)
            'applied': by_stamp('/pulsejet/applied_command', lambda m: list(m.position)),
        }
        return states, h.exit_codes
    finally:
        if recorder.poll() is None:
            recorder.kill()
        stop.set()
        for p in burners:
            p.join(5)


def differences(idle: dict, loaded: dict) -> str:
    """List the entries that differ between two runs, by topic and stamp (ns)."""
    lines = []
    for topic in sorted(set(idle) | set(loaded)):
        a, b = idle.get(topic, {}), loaded.get(topic, {})
        for stamp in sorted(set(a) | set(b)):
            if a.get(stamp, 'missing') != b.get(stamp, 'missing'):
                lines.append(
                    f'{topic} at {stamp} ns: idle {a.get(stamp, "missing")!r}, '
                    f'loaded {b.get(stamp, "missing")!r}'
                )
    return 'runs differ:\n' + '\n'.join(lines[:40])


@pytest.mark.timeout(300)
def test_closed_loop_is_deterministic_under_load(monkeypatch, tmp_path):
    domain = isolate_ros(monkeypatch, 41)
    idle, codes = closed_loop_run(domain, False, tmp_path / 'idle')
    assert codes.get('sim_node') == 0, codes
    loaded, codes = closed_loop_run(domain, True, tmp_path / 'loaded')
    assert codes.get('sim_node') == 0, codes
    assert max(idle['velocity']) == max(loaded['velocity']) == 1_500_000_000  # ns: the duration
    assert len(idle['velocity']) == 76  # t = 0 and 75 periods
    assert idle == loaded, differences(idle, loaded)  # bit for bit
    assert (
        len({tuple(p) for p in idle['applied'].values()}) >= 2
    )  # the routine did command something
    assert max(abs(v) for v in idle['velocity'].values()) > 0.0
