"""Shell model energy: conservation without dissipation, and the ledger of the full model."""

import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.models.shell.model import ShellModel
import pytest
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
LEDGER_KEYS = {
    'stored_elastic',
    'stored_kinetic_vehicle',
    'stored_kinetic_outer_fluid',
    'stored_kinetic_internal',
    'in_actuation_work',
    'in_initial',
    'out_jet_kinetic',
    'out_drag',
    'out_viscous',
    'out_other',
    'closure_error',
    'closure_relative',
}


def free_scene(integrator, dt, vehicle=False):
    """Ellipsoidal mantle released from a radial perturbation; viscosity, drag and jet off."""
    return {
        'model': 'shell',
        'simulation': {'dt_s': dt, 'integrator': integrator},
        'geometry': {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': 0.05,
            'semi_axis_radial_m': 0.03,
            'opening_radius_m': 0.01,
        },
        'mesh': {'elements': 16},
        'material': {
            'youngs_modulus_pa': 40e3,
            'viscosity_pa_s': 0.0,
            'poisson_ratio': 0.3,
            'half_thickness_m': 1e-3,
            'density_kg_m3': 1100.0,
        },
        'fluid': {'density_kg_m3': 1000.0, 'added_mass_coefficient': 1.1},
        'vehicle': {'mass_kg': 0.1, 'initial_velocity_m_s': 0.2 if vehicle else 0.0},
        'terms': {
            'viscosity': False,
            'drag': False,
            'jet': False,
            'vehicle_motion': vehicle,
            'added_mass': True,
        },
        'initial': {'radial_perturbation_m': 2e-3},
    }


def run_free(integrator, dt, duration, vehicle=False, samples=200):
    model = ShellModel.from_scene(free_scene(integrator, dt, vehicle))
    state = model.initial_state()
    n = max(1, int(round(duration / samples / dt)))
    err, vol = [], []
    for k in range(samples):
        model.advance(state, k * n * dt, n, Command())
        err.append(model.energy_ledger(state)['closure_relative'])
        vol.append(model.observe(state, 0.0, Command()).volume_m3)
    vol = np.array(vol) - np.mean(vol)
    periods = np.count_nonzero(np.diff(np.sign(vol)) != 0) / 2
    return model, np.abs(err), periods


def test_verlet_conserves_energy_over_many_periods_second_order():
    model = ShellModel.from_scene(free_scene('verlet', 1e-6))
    bound = model.stable_step_s(model.initial_state())
    _, e1, periods = run_free('verlet', 0.25 * bound, 1.0)
    _, e2, _ = run_free('verlet', 0.125 * bound, 1.0)
    assert periods >= 10  # measured: 15 periods
    # bounded oscillation (no drift) of order dt^2: measured max 2.5e-3 -> 5.9e-4
    assert e1.max() < 5e-3
    assert e1[-50:].max() < 1.5 * e1[:50].max() + 1e-4  # no secular drift
    assert e1.max() / e2.max() > 3.0


def test_implicit_midpoint_conserves_energy_with_moving_vehicle():
    model, err, periods = run_free('implicit_midpoint', 2e-4, 1.0, vehicle=True)
    assert periods >= 10
    assert err.max() < 2e-3  # measured: 5.0e-4
    led = model.energy_ledger(model.initial_state())
    assert led['in_initial'] > 0


@pytest.mark.parametrize(
    'name, tol', [('shell_robot', 1e-5), ('shell_ellipsoid', 1e-5), ('shell_cone', 5e-4)]
)
def test_ledger_closes_for_the_shipped_scenes(name, tol):
    scene = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    model.advance(state, 0.0, int(round(2.0 / model.dt_s)), Command())
    led = model.energy_ledger(state)
    assert set(led) == LEDGER_KEYS
    assert all(np.isfinite(v) for v in led.values())
    assert led['in_actuation_work'] > 0  # the actuator did work
    for key in ('out_jet_kinetic', 'out_drag', 'out_viscous'):
        assert led[key] > 0, key
    assert abs(led['closure_relative']) < tol, led
    obs = model.observe(state, 2.0, Command())
    assert obs.velocity_m_s > 0.01  # it swims forward
    assert obs.mantle_radius_m > 0 and obs.volume_m3 > 0


def test_dissipation_terms_are_nonnegative_and_viscosity_dominates_for_robot():
    scene = yaml.safe_load((CONFIG / 'shell_robot.yaml').read_text())
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    model.advance(state, 0.0, int(round(1.0 / model.dt_s)), Command())
    led = model.energy_ledger(state)
    assert led['out_viscous'] > led['out_drag'] > 0
    assert led['out_other'] >= 0
