"""
Shell model: the Newton workspace kept across advance() calls, and the lean observation.

With ``simulation.keep_newton_workspace: true`` the factorised Newton matrix and the predictor's
history carry over from one ``advance`` call to the next that continues it, so stepping in
publication periods gives the bits of one long call; anything that breaks the continuation (a
reset, a state set from outside, a changed parameter) starts the solve afresh.
"""

import numpy as np
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.scene import load_scene, SceneError
import pytest


def robot(**simulation):
    sim = {'keep_newton_workspace': True, 'newton_tolerance': 1e-9, **simulation}
    over = {'mesh': {'elements': 16}, 'simulation': sim}
    return load_scene('shell_robot', over).model


def test_periods_with_a_kept_workspace_give_the_bits_of_one_call():
    model = robot()
    periods = Simulation(model)
    for _ in range(60):
        periods.step(1)
    one = Simulation(model)
    one.step(60)
    assert np.array_equal(periods.state, one.state)
    tail = 6 * model.n_nodes
    # the factorisation is reused across the periods: far fewer than one per step
    assert periods.state[tail + sk.S_NJAC] < 0.5 * 60


def test_per_call_workspace_starts_every_call_afresh():
    model = robot(keep_newton_workspace=False)
    periods = Simulation(model)
    for _ in range(60):
        periods.step(1)
    tail = 6 * model.n_nodes
    assert periods.state[tail + sk.S_NJAC] == 60  # one factorisation per call
    one = Simulation(model)
    one.step(60)
    assert not np.array_equal(periods.state, one.state)  # a different (converged) Newton path
    rel = np.abs(periods.state[:tail] - one.state[:tail]) / (np.abs(one.state[:tail]) + 1e-3)
    assert rel.max() < 1e-5


def test_reset_and_a_state_set_from_outside_start_afresh():
    model = robot()
    sim = Simulation(model)
    for _ in range(30):
        sim.step(1)
    first = sim.state.copy()
    sim.reset()
    for _ in range(30):
        sim.step(1)
    assert np.array_equal(sim.state, first)  # as if the first run had not happened
    # a state written from outside (a run of another model of the same scene): not the state
    # this model's last call left, so the continuation is not recognised
    other = Simulation(robot())
    other.step(10)
    sim.state[:] = other.state
    sim.steps = 10
    sim.step(5)
    fresh = Simulation(model)
    fresh.state[:] = other.state
    fresh.steps = 10
    model.reset_workspace()
    fresh.step(5)
    assert np.array_equal(sim.state, fresh.state)


def test_a_changed_parameter_starts_afresh():
    model = robot()
    sim = Simulation(model)
    sim.step(5)
    J, W = model._workspace
    assert W[sk.WS_HAVE_LU] == 1.0
    before = sim.state[6 * model.n_nodes + sk.S_NJAC]
    sim.step(1)
    assert sim.state[6 * model.n_nodes + sk.S_NJAC] == before  # reused
    model.P[sk.P_TOL] *= 0.5
    sim.step(1)
    assert sim.state[6 * model.n_nodes + sk.S_NJAC] == before + 1  # refactorised at once


@pytest.mark.parametrize(
    'simulation, words',
    [
        ({'keep_newton_workspace': 'yes'}, "'yes' is not a boolean"),
        ({'keep_newton_workspace': True, 'specialise_kernel': True}, 'specialise_kernel: true'),
        ({'newton_tolerance': 1e-3}, 'newton_tolerance'),
    ],
)
def test_bad_solver_settings_are_refused_by_name(simulation, words):
    with pytest.raises(SceneError) as err:
        load_scene('shell_robot', {'simulation': simulation})
    assert words in str(err.value)


def test_verlet_accepts_the_setting_and_has_no_newton_to_keep():
    model = load_scene(
        'shell_robot',
        {'simulation': {'integrator': 'verlet', 'dt_s': 1e-6}, 'mesh': {'elements': 8}},
    ).model
    assert model.keep_newton_workspace
    sim = Simulation(model)
    sim.step(20)
    assert model._workspace is None


def test_observed_volume_is_the_force_evaluations_bit_for_bit():
    model = robot()
    sim = Simulation(model)
    sim.step(40)
    st, _, _, _ = model._eval(sim.state)
    assert sim.observe().volume_m3 == float(st[sk.T_VOL])
