"""
Shell model: measured convergence order in the time step.

The mesh order is in test_shell_static.
"""

import copy
import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.models.shell.model import ShellModel
import pytest
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
BASE = yaml.safe_load((CONFIG / 'shell_robot.yaml').read_text())
BASE['mesh']['elements'] = 12
# the order in the step needs converged solves: the schema's Newton tolerance, not the shipped
# scene's (chosen for its own error budget)
BASE['simulation']['newton_tolerance'] = 1e-9


def run(dt, integrator, duration=0.3):
    """
    Run the robot scene (full physics) through the first contraction.

    Full physics: cable, viscosity, jet, drag, vehicle.
    """
    scene = copy.deepcopy(BASE)
    scene['simulation'].update(dt_s=dt, integrator=integrator)
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    model.advance(state, 0.0, int(round(duration / dt)), Command())
    obs = model.observe(state, duration, Command())
    r, _ = model.profile(state)
    return np.array([obs.velocity_m_s, obs.volume_m3, r[6]])


@pytest.mark.parametrize(
    'integrator, low, high', [('implicit_midpoint', 1.8, 2.4), ('backward_euler', 0.85, 1.4)]
)
def test_time_step_order(integrator, low, high):
    ref = run(1.25e-4, integrator)
    errs = [np.abs(run(dt, integrator) - ref) / np.abs(ref) for dt in (4e-3, 2e-3, 1e-3)]
    orders = np.array([np.log2(errs[k] / errs[k + 1]) for k in range(2)])
    # measured: midpoint 2.0-2.1 (speed, volume, radius); backward Euler 1.04-1.10
    assert np.all(orders > low) and np.all(orders < high), orders
    if integrator == 'implicit_midpoint':
        assert errs[1].max() < 1e-4  # 2 ms steps are accurate to 1e-4 relative


def test_default_robot_step_is_accurate_against_a_fine_step():
    coarse = run(BASE['simulation']['dt_s'], 'implicit_midpoint', duration=0.6)
    fine = run(2.5e-4, 'implicit_midpoint', duration=0.6)
    assert np.max(np.abs(coarse - fine) / np.abs(fine)) < 1e-3
