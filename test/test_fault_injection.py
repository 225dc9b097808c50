"""Fault injection over real DDS: the controller is killed hard mid-run; sim_node's command
watchdog applies the safe command within its timeout of simulated time and says so."""
import signal

import pytest

from pulsejet_sim.engine.session import SAFE_COMMAND
from pulsejet_sim.harness import SimHarness
from conftest import isolate_ros

WARN = 1


@pytest.mark.timeout(180)
def test_watchdog_applies_the_safe_command_when_the_controller_dies(monkeypatch):
    domain = isolate_ros(monkeypatch, 71)
    with SimHarness(scene='pump_cycle', controller=True, domain_id=domain,
                    parameters={'watchdog_timeout_s': 0.3, 'watchdog_action': 'safe', 'diagnostics_period_s': 0.2},
                    controller_parameters={'rate_hz': 20.0}) as h:
        # the routine starts by inflating: pump on, valve shut
        h.spin_until(lambda: any(c.pump_flow_m3_s > 0 for _, c, _ in h.applied), 60.0, 'the pump to be commanded')
        controller = h.processes.pop('controller_node')    # killed on purpose: not a failure of the run
        controller.proc.send_signal(signal.SIGKILL)
        assert controller.stop() == -signal.SIGKILL
        t_kill = h.latest.time_s
        h.spin_until(lambda: h.applied and h.applied[-1][1] == SAFE_COMMAND, 30.0, 'the safe command')
        t_safe = h.applied[-1][0]
        assert t_safe - t_kill < 0.3 + 0.2      # the timeout plus the controller's last period and a publication
        d = h.wait_for_diagnostics(lambda d: 'watchdog tripped' in d.message, 10.0, 'a watchdog diagnostic')
        assert d.level == WARN and d.values['watchdog'] == 'tripped (safe)'
        assert 'command watchdog tripped' in h.output()
    assert h.exit_codes.get('sim_node') == 0
