"""The shell's scene keys are declared once (models/shell/scene_keys.py) and read by that table."""

from __future__ import annotations

import copy
from pathlib import Path

from pulsejet_sim.core.model_io import ModelError
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell import scene_keys as keys
from pulsejet_sim.models.shell.model import ShellModel
import pytest
import yaml

CONFIG = Path(__file__).resolve().parent.parent / 'config'
SHELL_SCENES = [p for p in sorted(CONFIG.glob('*.yaml'))
                if yaml.safe_load(p.read_text()).get('model') == 'shell']
ROBOT = yaml.safe_load((CONFIG / 'shell_robot.yaml').read_text())


def robot(**sections):
    scene = copy.deepcopy(ROBOT)
    for name, values in sections.items():
        scene[name] = dict(scene.get(name) or {}, **values)
    return scene


@pytest.mark.parametrize('path', SHELL_SCENES, ids=lambda p: p.stem)
def test_every_key_of_the_shipped_scenes_is_declared(path):
    scene = yaml.safe_load(path.read_text())
    for section, values in scene.items():
        if not isinstance(values, dict):
            assert section in keys.SECTIONS
            continue
        spec = (keys.GEOMETRY_KIND_SPEC | keys.GEOMETRY_SPECS[values['kind']]
                if section == 'geometry' else keys.SECTION_SPECS[section])
        assert set(values) <= set(spec), (section, set(values) - set(spec))


def test_declared_defaults_are_the_defaults_the_model_applies():
    scene = robot()
    for name in ('newton_tolerance', 'keep_newton_workspace', 'duration_s'):
        scene['simulation'].pop(name, None)
    scene['fluid'].pop('added_mass_coefficient')
    scene['jet'].pop('thrust_coefficient')
    scene['actuation'].pop('distribution')
    model = ShellModel.from_scene(scene)
    sim, jet, act = keys.SIMULATION_SPEC, keys.JET_SPEC, keys.ACTUATION_SPEC
    assert model.P[sk.P_TOL] == sim['newton_tolerance'].rule.default
    assert model.keep_newton_workspace is sim['keep_newton_workspace'].rule.default
    assert model.duration_s == sim['duration_s'].rule.default
    assert model.P[sk.P_CF] == jet['thrust_coefficient'].rule.default
    assert model.P[sk.P_FORMATION_NUMBER] == 0.0  # no starting jet: its default is off
    assert model.actuation['distribution'] == act['distribution'].rule.default
    assert model.actuation['start_delay_s'] == act['start_delay_s'].rule.default
    assert model.actuation['pulse'] == act['pulse'].rule.default
    assert model.integrator == ShellModel.from_scene(robot()).integrator
    # derived defaults, as their words say
    assert model.actuation['max_cable_force_n'] == 2.0 * model.actuation['amplitude']
    fluid = ShellModel.from_scene(robot(fluid={'added_mass_coefficient': 1.1}))
    assert fluid.node_added_mass.sum() == model.node_added_mass.sum()


@pytest.mark.parametrize(
    'sections, words',
    [
        ({'simulation': {'rtol': 1e-6}},
         'simulation.rtol: unknown key (value 1e-06); allowed: dt_s, duration_s, publish_rate_hz'),
        # a bound derived from the scene is printed with the scene's value
        ({'jet': {'outlet_radius_m': 0.05}},
         'jet.outlet_radius_m: 0.05 is out of range; allowed: a finite number in [0.0001, '
         '0.0219203] m'),
        ({'actuation': {'contraction_s': 0.7}},
         'actuation.contraction_s: 0.7 is out of range; allowed: a finite number in (0, 0.625] s'),
        ({'mesh': {'elements': 12.0}},
         'mesh.elements: 12.0 is not a whole number; allowed: a whole number in [4, 400]'),
        ({'mesh': {'elements': 401}},
         'mesh.elements: 401 is out of range; allowed: a whole number'),
        ({'actuation': {'amplitude': 1e4}},
         'actuation.amplitude: 10000.0 is out of range; allowed: a finite number in [0, 1000] N'),
        ({'simulation': {'integrator': 'rk4'}},
         "simulation.integrator: 'rk4' is not known; allowed: one of verlet, implicit_midpoint, "
         'backward_euler'),
        ({'geometry': {'cap_radius_m': 'wide'}},
         "geometry.cap_radius_m: 'wide' is not a number; allowed: a finite number in "
         '[0.001, 10] m'),
    ],
)
def test_refusals_name_the_key_the_value_and_what_is_allowed(sections, words):
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(robot(**sections))
    assert words in str(err.value)


def test_a_missing_key_says_what_it_takes():
    scene = robot()
    del scene['geometry']['kind']
    with pytest.raises(ModelError, match='geometry.kind: missing; allowed: one of ellipsoid, '):
        ShellModel.from_scene(scene)
    scene = robot()
    del scene['material']['poisson_ratio']
    with pytest.raises(ModelError, match=r'material.poisson_ratio: missing; allowed: a finite '
                                         r'number in \[0, 0.49\]'):
        ShellModel.from_scene(scene)


def test_numbers_written_as_text_still_read_as_before():
    """The shell (like its geometry) reads what float() reads; the bits do not change."""
    as_text = ShellModel.from_scene(robot(material={'youngs_modulus_pa': '4.0e4'}))
    as_number = ShellModel.from_scene(robot())
    assert as_text.P.tobytes() == as_number.P.tobytes()


def test_no_actuation_ignores_the_routines_keys_but_not_unknown_ones():
    off = ShellModel.from_scene(robot(actuation={'kind': 'none'}))  # merged over the robot's
    assert off.actuation == {'kind': 'none', 'source': 'none'}
    with pytest.raises(ModelError, match=r"actuation.colour: unknown key \(value 'red'\)"):
        ShellModel.from_scene(robot(actuation={'kind': 'none', 'colour': 'red'}))
    with pytest.raises(ModelError, match='actuation.taper_fraction: unknown key'):
        ShellModel.from_scene(robot(actuation={'taper_fraction': 0.1}))  # a muscle key
