"""The shell's batched energy ledgers (energy_ledgers, the offline recording's) are its ledgers."""

import numpy as np
from pulsejet_sim.scene import load_scene
from pulsejet_sim.studies.runner import Drive
import pytest


@pytest.mark.timeout(300)
@pytest.mark.parametrize('name, isotropic', [
    ('shell_robot', False), ('shell_robot', True), ('shell_cone', False),
])
def test_energy_ledgers_are_energy_ledger_of_each_state_bit_for_bit(name, isotropic):
    drive = Drive(load_scene(name), 0.6)
    model = drive.sim.model
    if isotropic:  # the added mass of the authors' code (an instance's choice)
        model.isotropic_added_mass = True
    states = [drive.sim.state.copy()]
    for _ in drive:
        states.append(drive.sim.state.copy())
    states = np.array(states)
    states[1, 3 * model.n_nodes] = np.nan  # a non-finite velocity goes through alike
    batched = model.energy_ledgers(states)
    single = [model.energy_ledger(state) for state in states]
    # repr: the recorded text, and bits (nan == nan, -0.0 != 0.0)
    assert [repr(ledger) for ledger in batched] == [repr(ledger) for ledger in single]
    assert len(single) == 61 and len(single[0]) > 10
