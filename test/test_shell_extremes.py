"""
Shell model extremes: each case runs stable or is refused with a reason; never NaN.

Shell model extremes: each case either runs stable with the ledger closing, or is refused before
running with a message that says why and what would work.  Never NaN.
"""

import copy
import math
import pathlib
import re

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError, SimulationBlowUp
from pulsejet_sim.models.shell.model import ShellModel
import pytest
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
ROBOT = yaml.safe_load((CONFIG / 'shell_robot.yaml').read_text())
# These tests fix their own numerics (the robot's physics on a 24-element mesh at 2 ms), so that a
# change of the shipped scene's default mesh or step does not change what they check.
ROBOT['mesh']['elements'] = 24
ROBOT['simulation']['dt_s'] = 2.0e-3
CONE = yaml.safe_load((CONFIG / 'shell_cone.yaml').read_text())


def scene(base, **over):
    sc = copy.deepcopy(base)
    for key, value in over.items():
        sec, name = key.split('__')
        sc.setdefault(sec, {})[name] = value
    return sc


def run(sc, duration=2.0, chunk=0.02):
    model = ShellModel.from_scene(sc)
    state = model.initial_state()
    n = int(round(chunk / model.dt_s))
    vmin = math.inf
    t = 0.0
    for _ in range(int(round(duration / chunk))):
        model.advance(state, t, n, Command())
        t += n * model.dt_s
        obs = model.observe(state, t, Command())
        values = [getattr(obs, f) for f in obs.__dataclass_fields__]
        assert all(math.isfinite(v) for v in values)
        vmin = min(vmin, obs.volume_m3)
    assert np.all(np.isfinite(state))
    return model, state, vmin


CASES = {
    # name: (scene, duration, closure tolerance)   measured closure at 2 s in brackets
    'soft_1kPa_collapses_onto_axis': (
        scene(ROBOT, material__youngs_modulus_pa=1e3),
        2.0,
        2e-2,
    ),  # 6.4e-3
    'stiff_10MPa': (
        scene(ROBOT, material__youngs_modulus_pa=1e7, actuation__amplitude=200.0),
        1.0,
        1e-5,
    ),
    'no_viscosity': (scene(ROBOT, material__viscosity_pa_s=0.0), 2.0, 1e-5),  # 8e-7
    'high_viscosity_5e4': (scene(ROBOT, material__viscosity_pa_s=5e4), 1.0, 1e-5),
    'fine_mesh_200': (scene(ROBOT, mesh__elements=200), 0.4, 1e-5),
    'pulsation_5Hz': (
        scene(
            ROBOT,
            actuation__frequency_hz=5.0,
            actuation__contraction_s=0.08,
            actuation__release_s=0.1,
        ),
        1.0,
        1e-5,
    ),
    'cone_85pct_volume_change': (scene(CONE, actuation__amplitude=0.8), 1.0, 5e-4),  # 4.5e-5
}


@pytest.mark.parametrize('name', list(CASES))
def test_extreme_case_runs_with_closed_ledger(name):
    sc, duration, tol = CASES[name]
    model, state, vmin = run(sc, duration)
    led = model.energy_ledger(state)
    assert abs(led['closure_relative']) < tol, (name, led['closure_relative'])
    if name == 'cone_85pct_volume_change':
        assert vmin < 0.2 * model.ref.volume_m3()  # > 80 % of the volume expelled
    if name == 'soft_1kPa_collapses_onto_axis':
        r, _ = model.profile(state)
        assert r.min() >= 0.0  # axis contact holds the wall off the axis


def test_closure_of_violent_collapse_improves_with_smaller_step():
    errs = []
    for dt in (2e-3, 5e-4):
        sc = scene(ROBOT, actuation__amplitude=100.0, simulation__dt_s=dt)
        model, state, vmin = run(sc, 0.6)
        assert vmin < 0.1 * model.ref.volume_m3()
        errs.append(abs(model.energy_ledger(state)['closure_relative']))
    assert errs[1] < 0.5 * errs[0] and errs[1] < 1e-2


def test_explicit_scheme_refused_above_its_stable_step_with_the_bound_and_a_remedy():
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(
            scene(ROBOT, material__youngs_modulus_pa=1e7, simulation__integrator='verlet')
        )
    msg = str(err.value)
    assert 'simulation.dt_s' in msg and 'stable step' in msg and 'implicit_midpoint' in msg


def test_explicit_scheme_at_its_stable_step_runs_and_beyond_blows_up_cleanly():
    sc = scene(
        ROBOT,
        mesh__elements=8,
        material__viscosity_pa_s=0.0,
        simulation__integrator='verlet',
        simulation__dt_s=1e-7,
        actuation__amplitude=20.0,
    )
    model = ShellModel.from_scene(sc)
    bound = model.stable_step_s(model.initial_state())
    ok = ShellModel.from_scene(scene(sc, simulation__dt_s=0.95 * bound))
    state = ok.initial_state()
    ok.advance(state, 0.0, int(0.03 / ok.dt_s), Command())
    assert np.all(np.isfinite(state))
    # force a step beyond the bound (bypassing the refusal) -> SimulationBlowUp, state kept finite
    import pulsejet_sim.models.shell.kernels as sk

    ok.dt_s = 2.0 * bound
    ok.P[sk.P_DT] = 2.0 * bound
    state = ok.initial_state()
    with pytest.raises(SimulationBlowUp) as err:
        ok.advance(state, 0.0, int(0.03 / ok.dt_s), Command())
    assert 'state kept at the last good step' in str(err.value)
    assert np.all(np.isfinite(state))
    assert err.value.time_s > 0


def test_routine_not_resolved_by_the_step_is_refused():
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(
            scene(
                ROBOT,
                actuation__frequency_hz=5.0,
                actuation__contraction_s=0.08,
                actuation__release_s=0.1,
                simulation__dt_s=0.01,
            )
        )
    assert 'dt_s' in str(err.value) and '0.008' in str(err.value)


def test_random_scenes_never_produce_nan():
    """
    Seeded random scenes across the allowed ranges never produce NaN.

    Seeded random scenes across the allowed ranges: each is refused (ModelError), runs with
    finite state and ledger, or stops with SimulationBlowUp at a finite last good state and a
    message that says what would work.
    """
    rng = np.random.default_rng(7)
    outcomes = []
    for k in range(12):
        base = copy.deepcopy([ROBOT, CONE][k % 2])
        base['mesh']['elements'] = int(rng.integers(4, 60))
        base['material']['youngs_modulus_pa'] = float(10 ** rng.uniform(3, 7))
        base['material']['viscosity_pa_s'] = float(rng.choice([0.0, 10 ** rng.uniform(0, 4.5)]))
        base['material']['poisson_ratio'] = float(rng.uniform(0, 0.49))
        base['simulation']['integrator'] = str(
            rng.choice(['implicit_midpoint', 'backward_euler', 'verlet'])
        )
        base['simulation']['dt_s'] = float(10 ** rng.uniform(-3.5, -2.3))
        act = base['actuation']
        act['amplitude'] = (
            float(10 ** rng.uniform(0, 1.7))
            if act['kind'] == 'cable'
            else float(rng.uniform(0, 0.9))
        )
        try:
            model = ShellModel.from_scene(base)
        except ModelError as err:
            assert 'allowed' in str(err)
            outcomes.append('refused')
            continue
        state = model.initial_state()
        try:
            model.advance(state, 0.0, int(round(0.3 / model.dt_s)), Command())
            led = model.energy_ledger(state)
            assert all(math.isfinite(v) for v in led.values())
            outcomes.append('ok')
        except SimulationBlowUp as err:
            assert 'what would work' in str(err) or 'NaN' not in str(err)
            outcomes.append('blowup')
        assert np.all(np.isfinite(state))
    assert outcomes.count('ok') >= 4, outcomes


CABLE_SCENES = sorted(
    p.stem
    for p in CONFIG.glob('*.yaml')
    if (yaml.safe_load(p.read_text()).get('actuation') or {}).get('kind') == 'cable'
)


@pytest.mark.parametrize('name', CABLE_SCENES)
def test_cable_commands_up_to_the_rating_never_blow_a_shipped_scene_up(name):
    """Hold, and toggle every step and every 10 steps, at the cable's rating: the physics runs."""
    from pulsejet_sim.core.model_io import CommandError
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.scene import load_scene

    model = load_scene(name, command_driven=True).model
    low, rating = Simulation(model).command_limits['cable_force_n']
    assert 0.0 < rating < Command.LIMITS['cable_force_n'][1]
    patterns = {
        'hold': lambda k: 1,
        'toggle every step': lambda k: k % 2,
        'toggle every 10 steps': lambda k: (k // 10) % 2,
    }
    for pattern, on in patterns.items():
        sim = Simulation(model)
        for k in range(int(round(1.0 / model.dt_s))):
            try:
                obs = sim.step(1, Command(cable_force_n=rating * on(k)))
            except SimulationBlowUp as err:
                pytest.fail(f'{name}, {pattern} at the {rating:g} N rating: {err}')
        assert math.isfinite(obs.velocity_m_s) and math.isfinite(obs.volume_m3)
    # above the rating the command is refused, naming the value and the scene's range
    # (the message gives the rating as stored: 6 significant digits may round it up)
    allowed = re.escape(repr(rating))
    with pytest.raises(CommandError, match=rf'cable_force_n=.*\[0\.0, {allowed}\]'):
        Simulation(model).step(1, Command(cable_force_n=1.01 * rating))
