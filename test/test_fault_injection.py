"""
Fault injection over real DDS: the controller is killed hard mid-run.

Fault injection over real DDS: the controller is killed hard mid-run; sim_node's command
watchdog applies the safe command within its timeout of simulated time and says so.
"""

import signal

from conftest import isolate_ros
from pulsejet_sim.engine.session import SAFE_COMMAND
from pulsejet_sim.ros.harness import SimHarness
import pytest

WARN = 1


@pytest.mark.timeout(180)
def test_watchdog_applies_the_safe_command_when_the_controller_dies(monkeypatch):
    domain = isolate_ros(monkeypatch, 71)
    with SimHarness(
        scene='pump_cycle',
        controller=True,
        domain_id=domain,
        parameters={
            'watchdog_timeout_s': 0.3,
            'watchdog_action': 'safe',
            'diagnostics_period_s': 0.2,
        },
        controller_parameters={'rate_hz': 20.0},
    ) as h:
        # the routine starts by inflating: pump on, valve shut
        h.spin_until(
            lambda: any(c.pump_flow_m3_s > 0 for _, c, _ in h.applied),
            60.0,
            'the pump to be commanded',
        )
        controller = h.processes.pop(
            'controller_node'
        )  # killed on purpose: not a failure of the run
        controller.proc.send_signal(signal.SIGKILL)
        assert controller.stop() == -signal.SIGKILL
        t_kill = h.latest.time_s
        h.spin_until(
            lambda: h.applied and h.applied[-1][1] == SAFE_COMMAND, 30.0, 'the safe command'
        )
        t_safe = h.applied[-1][0]
        assert (
            t_safe - t_kill < 0.3 + 0.2
        )  # the timeout plus the controller's last period and a publication
        d = h.wait_for_diagnostics(
            lambda d: 'watchdog tripped' in d.message, 10.0, 'a watchdog diagnostic'
        )
        assert d.level == WARN and d.values['watchdog'] == 'tripped (safe)'
        assert 'command watchdog tripped' in h.output()
    assert h.exit_codes.get('sim_node') == 0


@pytest.mark.timeout(240)
def test_a_restarted_sim_node_is_picked_up_by_the_controller_and_the_recorder(
    monkeypatch, tmp_path
):
    """
    A sim_node restarted mid-run is picked up by the controller and the recorder.

    sim_node killed hard mid-run and started again: controller_node (time went back: its routine
    restarts) and an in-process recorder go on without a restart; the recording holds both runs.
    """
    from pulsejet_sim.ros.launching import NodeProcess
    from pulsejet_sim.ros.recorder import Recorder
    from test_recorder import read_all

    domain = isolate_ros(monkeypatch, 73)
    out = tmp_path / 'run.mcap'
    with SimHarness(scene='pump_cycle', controller=True, domain_id=domain, log_dir=tmp_path) as h:
        recorder = Recorder(h.node, out, None)
        try:
            h.spin_until(lambda: h.time_s > 1.0, 60.0, 'the first run to pass 1 s')
            # ... in the recording too, before the kill. Once (fresh clone, 2026-12-02) the
            # recorded clock fell back from 0.15 s although the harness had seen 1.0 s; not
            # reproduced since. Either the recorder's callbacks lagged, or its reliable reader
            # held samples behind a lost one until the writer's repair (a killed writer sends
            # none): docs/dev/reliability.md. If the recorder stalls for good, this wait fails and
            # says so. At 100 Hz of /clock from t >= 0 (t = 0 at most twice), 105 messages reach
            # past 1.0 s.
            h.spin_until(
                lambda: recorder.message_counts.get('/clock', 0) >= 105,
                30.0,
                'the recorder to have the first run past 1 s',
            )
            first = h.processes.pop('sim_node')
            first.proc.send_signal(signal.SIGKILL)
            assert first.stop() == -signal.SIGKILL
            n_before = len(h.applied)
            # held at t = 0 until the controller's, the harness's and the recorder's /clock
            # subscriptions have discovered it (the compile cache makes the node start at once;
            # without the hold it could pass the old run's time before anyone sees it go back)
            params = {'scene': 'pump_cycle', 'pacing': 'real_time', 'wait_for_subscribers': 3}
            h.processes['sim_node'] = NodeProcess(
                'pulsejet_sim.ros.sim_node', params, tmp_path / 'sim_node.2.log', h.environment()
            )
            # the new run starts at t = 0 and the controller commands it again
            h.spin_until(
                lambda: 0.3 < h.time_s < 1.0 and len(h.applied) > n_before + 1,
                90.0,
                'the restarted run to be commanded',
            )
            h.spin_until(
                lambda: any(c.pump_flow_m3_s > 0 for _, c, _ in list(h.applied)[n_before:]),
                30.0,
                'the restarted routine to pump',
            )
        finally:
            recorder.close()
        assert h.processes['controller_node'].alive()
    ctrl_log = (tmp_path / 'controller_node.log').read_text()
    assert 'restarting the routine' in ctrl_log, ctrl_log[-2000:]
    clock = [m.clock.sec + 1e-9 * m.clock.nanosec for m in read_all(out)['/clock']]
    drop = max(range(1, len(clock)), key=lambda i: clock[i - 1] - clock[i])
    # the first run, then the second from 0
    assert clock[drop - 1] > 1.0 and clock[drop] < 0.2, (
        f'largest drop at message {drop} of {len(clock)}: {clock[max(0, drop - 5) : drop + 5]};'
        f' recorded clock from {clock[0]} to max {max(clock)}'
    )
