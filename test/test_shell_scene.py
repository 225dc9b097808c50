"""Shell model scene schema, geometries and the Model protocol API."""

import copy
import math
import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError, Observation
from pulsejet_sim.models.shell.geometry import build_reference_meridian
from pulsejet_sim.models.shell.model import ShellModel
import pytest
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
ROBOT = yaml.safe_load((CONFIG / 'shell_robot.yaml').read_text())
# These tests fix their own numerics (the robot's physics on a 24-element mesh at 2 ms, the
# schema's Newton tolerance 1e-9 solved afresh at each call), so that a change of the shipped
# scene's default mesh, step or solver settings does not change what they check.
ROBOT['mesh']['elements'] = 24
ROBOT['simulation']['dt_s'] = 2.0e-3
ROBOT['simulation']['newton_tolerance'] = 1e-9
ROBOT['simulation']['keep_newton_workspace'] = False


def scene(**over):
    sc = copy.deepcopy(ROBOT)
    for key, value in over.items():
        sec, name = key.split('__')
        sc.setdefault(sec, {})[name] = value
    return sc


@pytest.mark.parametrize('name', ['shell_robot', 'shell_ellipsoid', 'shell_cone'])
def test_shipped_scenes_build(name):
    model = ShellModel.from_scene(yaml.safe_load((CONFIG / f'{name}.yaml').read_text()))
    assert model.name == 'shell' and model.dt_s > 0
    s = model.initial_state()
    assert s.dtype == np.float64 and np.all(np.isfinite(s))


def test_robot_scene_matches_the_paper_figures():
    model = ShellModel.from_scene(ROBOT)
    r0, z0 = model.profile(model.initial_state())
    assert z0.max() - z0.min() == pytest.approx(0.16, rel=1e-3)  # 16 cm mantle
    assert r0.max() == pytest.approx(0.031 * math.sin(math.pi / 4), rel=1e-3)
    assert model.payload_kg + float(model.node_mass[:-1].sum()) == pytest.approx(0.335)
    assert model.P[7] == pytest.approx(math.pi * 0.0125**2)  # outlet area
    state = model.initial_state()
    vols = []
    for k in range(int(2.5 / 0.05)):
        model.advance(state, k * 0.05, int(round(0.05 / model.dt_s)), Command())
        vols.append(model.observe(state, 0.0, Command()).volume_m3)
    stroke = max(vols[-13:]) - min(vols[-13:])  # last 0.65 s, ~one period
    assert 25e-6 < stroke < 50e-6  # ~35 ml stroke volume


@pytest.mark.parametrize(
    'key, value, expect',
    [
        ('mesh__elements', 2, 'mesh.elements'),
        ('mesh__elements', 'many', 'mesh.elements'),
        ('material__youngs_modulus_pa', -5.0, 'material.youngs_modulus_pa'),
        ('material__poisson_ratio', 0.5, 'material.poisson_ratio'),
        ('material__half_thickness_m', 0.02, 'material.half_thickness_m'),
        ('geometry__kind', 'torus', 'geometry.kind'),
        ('simulation__integrator', 'rk45', 'simulation.integrator'),
        ('simulation__dt_s', 0.0, 'simulation.dt_s'),
        ('actuation__kind', 'pump', 'actuation.kind'),
        ('actuation__distribution', 'parabolic', 'actuation.distribution'),
        ('actuation__release_s', 0.6, 'release_s'),
        ('terms__jet', 'yes', 'terms.jet'),
        ('terms__magic', True, 'terms.magic'),
        ('vehicle__mass_kg', 0.01, 'vehicle.mass_kg'),
        ('jet__outlet_radius_m', 0.05, 'jet.outlet_radius_m'),
    ],
)
def test_bad_values_are_refused_naming_key_value_and_allowed(key, value, expect):
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(scene(**{key: value}))
    msg = str(err.value)
    assert expect in msg and 'allowed' in msg
    assert repr(value) in msg or str(value) in msg


def test_unknown_section_refused():
    sc = scene()
    sc['pump'] = {}
    with pytest.raises(ModelError, match='pump'):
        ShellModel.from_scene(sc)


@pytest.mark.parametrize(
    'geometry',
    [
        {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': 0.08,
            'semi_axis_radial_m': 0.03,
            'opening_radius_m': 0.016,
        },
        {'kind': 'cone', 'length_m': 0.16, 'base_radius_m': 0.03, 'tip_radius_m': 0.006},
        {'kind': 'cone', 'length_m': 0.16, 'base_radius_m': 0.03, 'tip_radius_m': 0.0},
        {
            'kind': 'cap_cylinder',
            'cap_radius_m': 0.031,
            'cap_opening_rad': math.pi / 4,
            'cylinder_length_m': 0.151,
        },
        {'kind': 'points', 'points': [[0.0, 0.1], [0.02, 0.09], [0.03, 0.05], [0.025, 0.0]]},
    ],
)
def test_geometries_sample_pole_to_ring(geometry):
    p = build_reference_meridian(geometry, 20)
    assert p.r0[0] == 0.0 and p.z0[-1] == 0.0 and np.all(p.r0[1:] > 0)
    ds = np.hypot(np.diff(p.r0), np.diff(p.z0))
    assert ds.max() / ds.min() < 1.5  # about equal arc length
    assert p.volume_m3() > 0
    if geometry['kind'] in ('ellipsoid', 'cap_cylinder') or geometry.get('tip_radius_m', 0) > 0:
        assert abs(p.theta0[0]) < 0.05  # smooth pole: radial director


def test_ellipsoid_volume_and_bad_points():
    a, b, ro = 0.05, 0.03, 1e-4
    p = build_reference_meridian(
        {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': a,
            'semi_axis_radial_m': b,
            'opening_radius_m': ro,
        },
        200,
    )
    assert p.volume_m3() == pytest.approx(4 / 3 * math.pi * a * b * b, rel=1e-3)
    with pytest.raises(ModelError, match='geometry.points'):
        build_reference_meridian(
            {'kind': 'points', 'points': [[0.01, 0.0], [0.02, 0.0], [0.03, 0.0]]}, 10
        )


def test_observation_profile_and_routine_command():
    model = ShellModel.from_scene(ROBOT)
    state = model.initial_state()
    model.advance(state, 0.0, 50, Command())  # 0.1 s into the contraction
    obs = model.observe(state, 0.1, Command())
    assert isinstance(obs, Observation)
    r, z = model.profile(state)
    assert (
        obs.mantle_radius_m == r[model.mid_node] < model.ref.r0[model.mid_node]
    )  # moves with the pull
    assert model.ref.X[model.mid_node] == pytest.approx(
        0.5 * model.ref.X[-1], abs=model.ref.X[-1] / 100
    )
    assert obs.volume_m3 < model.ref.volume_m3()  # contracting
    assert obs.jet_speed_m_s > 0 and obs.thrust_n > 0 and obs.cavity_pressure_pa > 0
    assert obs.fluid_mass_kg == pytest.approx(1022.0 * obs.volume_m3)
    assert model.routine_command(0.2).cable_force_n == pytest.approx(8.0)  # peak at contraction_s
    assert model.routine_command(0.55).cable_force_n == 0.0  # rest
    assert model.stable_step_s(state) > 0


@pytest.mark.parametrize('pulse', ['half_cosine', 'triangle'])
def test_built_in_routine_and_the_controllers_cable_routine_pull_alike(pulse):
    """The model's routine (numba) and pulsejet_ctrl's CableRoutine give the same pull."""
    from pulsejet_sim.routines import CableRoutine

    model = ShellModel.from_scene(scene(actuation__pulse=pulse, actuation__start_delay_s=0.05))
    act = model.actuation
    assert act['pulse'] == pulse
    controller = CableRoutine(
        act['amplitude'],
        act['frequency_hz'],
        act['contraction_s'],
        act['release_s'],
        act['start_delay_s'],
        pulse,
    )
    times = np.linspace(0.0, 3.0 / act['frequency_hz'], 301)
    pulls = [model.routine_command(t).cable_force_n for t in times]
    assert pulls == pytest.approx([controller.command(t).cable_force_n for t in times], abs=1e-12)
    quarter = act['start_delay_s'] + 0.25 * act['contraction_s']
    linear = {'half_cosine': 0.5 * (1 - math.cos(math.pi / 4)), 'triangle': 0.25}[pulse]
    assert model.routine_command(quarter).cable_force_n == pytest.approx(act['amplitude'] * linear)


def test_a_pulse_shape_that_is_not_known_is_refused():
    with pytest.raises(ModelError, match=r"actuation.pulse.*'square'.*half_cosine.*triangle"):
        ShellModel.from_scene(scene(actuation__pulse='square'))


def test_cable_force_from_command():
    sc = scene(actuation__source='command')
    model = ShellModel.from_scene(sc)
    s1, s2 = model.initial_state(), model.initial_state()
    model.advance(s1, 0.0, 100, Command(cable_force_n=0.0))
    model.advance(s2, 0.0, 100, Command(cable_force_n=5.0))
    v0 = model.ref.volume_m3()
    assert model.observe(s1, 0.2, Command()).volume_m3 == pytest.approx(v0, rel=1e-9)
    assert model.observe(s2, 0.2, Command()).volume_m3 < 0.97 * v0
    assert model.energy_ledger(s2)['in_actuation_work'] > 0


def test_reference_state_is_an_exact_equilibrium():
    """
    No actuation: the sampled reference shape is stress free and stays at rest.

    All terms on.
    """
    for name in ('shell_robot', 'shell_cone'):
        sc = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
        sc['actuation'] = {'kind': 'none'}
        model = ShellModel.from_scene(sc)
        state = model.initial_state()
        start = state.copy()
        model.advance(state, 0.0, 200, Command())
        n = 3 * model.n_nodes
        assert np.max(np.abs(state[: 2 * n] - start[: 2 * n])) < 1e-12
        assert model.energy_ledger(state)['stored_elastic'] < 1e-20


def test_points_profile_runs_through_the_scene_loader():
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.scene import scene_from_dict

    sc = scene(geometry__kind='points')
    sc['geometry'] = {
        'kind': 'points',
        'points': [[0.0, 0.12], [0.015, 0.115], [0.025, 0.09], [0.025, 0.03], [0.02, 0.0]],
    }
    sc['mesh'] = {'elements': 16}
    sim = Simulation(scene_from_dict(sc, name='points').model)
    obs = sim.step(250)
    assert obs.time_s == pytest.approx(0.5)
    assert obs.velocity_m_s > 0
    assert abs(sim.energy_ledger()['closure_relative']) < 1e-5
    r, z = sim.profile()
    assert r.shape == z.shape == (17,)
