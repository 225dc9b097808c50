"""The atomic command message (pulsejet_sim.ros.messages): built and parsed by the same names."""

from pulsejet_sim.models.base import Command
from pulsejet_sim.ros import messages
import pytest


def test_a_command_naming_some_actuators_parses_back_to_exactly_those():
    cmd = Command(pump_flow_m3_s=2.5e-3, valve_opening=0.0, cable_force_n=7.0)
    msg = messages.command_message(cmd, 1.25, fields=('pump_flow_m3_s', 'valve_opening'))
    assert messages.command_values(msg) == (1.25, {'pump_flow_m3_s': 2.5e-3, 'valve_opening': 0.0})
    _, every = messages.command_values(messages.command_message(cmd, 1.25))
    assert every == {'pump_flow_m3_s': 2.5e-3, 'valve_opening': 0.0, 'cable_force_n': 7.0}


@pytest.mark.parametrize('fields', [(), ('pump_flow_m3_s', 'pump_flow_m3_s'), ('thrust_n',)])
def test_a_command_with_bad_fields_is_refused_naming_them(fields):
    with pytest.raises(ValueError, match=r'fields .* rejected; allowed: distinct names from'):
        messages.command_message(Command(), 0.0, fields=fields)
