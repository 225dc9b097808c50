"""
Fingerprint what the shell model builds from its scenes, to show a refactoring keeps every bit.

    .venv/bin/python scripts/shell_scene_bits.py --write BASE.json   # record (before the change)
    .venv/bin/python scripts/shell_scene_bits.py --check BASE.json   # compare (after): 1 on a diff

For every shipped shell scene (config/*.yaml with ``model: shell``), every validation case
(validation/cases/) on a shell scene with its overrides and its probes' overrides, and a set of
variants that reach the other branches of the scene reader (couplings, outlets, muscle, water
inside, starting jet, integrators, command-driven), the model is built through the public API
(``load_scene``, ``Simulation``) and stepped about 1 s; the sha256 of its packed parameters
(P, E, Nd and the node masses), of its scene-derived attributes and of the final state bytes are
recorded. A list of bad inputs records the exact refusal text, so a change of wording shows.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
from pathlib import Path
import sys

import numpy as np
from pulsejet_sim.core.schema import read_yaml_file
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.scene import load_scene, SceneError
from pulsejet_sim.scene.loader import merge

ROOT = Path(__file__).resolve().parent.parent  # the venv's editable install imports the package

STEP_S = 1.0
MAX_STEPS = 2000  # the verlet variants' tiny steps: a bounded number of them

# variants beyond the shipped files: (name, scene, overrides, command_driven)
CONE_EDGE = {'jet': {'outlet': 'edge'}}
VARIANTS = [
    ('cone_paper', 'shell_cone', {'coupling': 'paper', 'jet': {'outlet_radius_m': None}}, False),
    ('cone_paper_code', 'shell_cone',
     {'coupling': 'paper_code', 'jet': {'outlet': 'free_edge_fixed_nozzle'}}, False),
    ('cone_paper_code_default_outlet', 'shell_cone',
     {'coupling': 'paper_code', 'jet': {'outlet_radius_m': None}}, False),
    ('cone_edge', 'shell_cone', {'jet': {'outlet': 'edge', 'outlet_radius_m': None}}, False),
    ('cone_edge_water_1d', 'shell_cone',
     {'jet': {'outlet': 'edge', 'outlet_radius_m': None},
      'fluid': {'internal_inertia': 'one_dimensional', 'internal_flow_momentum': True}}, False),
    ('cone_edge_water_deforming', 'shell_cone',
     {'jet': {'outlet': 'edge', 'outlet_radius_m': None},
      'fluid': {'internal_inertia': 'one_dimensional_deforming'}}, False),
    ('cone_paper_water_1d', 'shell_cone',
     {'coupling': 'paper', 'jet': {'outlet_radius_m': None},
      'fluid': {'internal_inertia': 'one_dimensional', 'internal_flow_momentum': True}}, False),
    ('cone_muscle_constant_depth', 'shell_cone',
     {'actuation': {'desired_radius': 'constant_depth', 'taper_fraction': 0.2,
                    'pulse': 'triangle', 'start_delay_s': 0.05}}, False),
    ('cone_muscle_to_edge', 'shell_cone',
     {'actuation': {'desired_radius': 'constant_depth_to_edge'}}, False),
    ('cone_backward_euler', 'shell_cone', {'simulation': {'integrator': 'backward_euler'}}, False),
    ('cone_no_actuation', 'shell_cone',
     {'actuation': {'kind': 'none'}, 'initial': {'radial_perturbation_m': 0.002},
      'load': {'internal_pressure_pa': 50.0}}, False),
    ('cone_neo_hookean', 'shell_cone',
     {'material': {'law': 'neo_hookean', 'shear_modulus_pa': 3.0e4, 'youngs_modulus_pa': None,
                   'poisson_ratio': None}}, False),
    ('robot_neo_hookean_silicone', 'shell_robot',
     {'material': {'law': 'neo_hookean', 'silicone': 'ecoflex_00_30', 'youngs_modulus_pa': None,
                   'poisson_ratio': None}}, False),
    ('cone_verlet', 'shell_cone',
     {'simulation': {'integrator': 'verlet', 'dt_s': 1e-6}, 'mesh': {'elements': 8}}, False),
    ('robot_rising_triangle', 'shell_robot',
     {'actuation': {'distribution': 'rising', 'pulse': 'triangle', 'start_delay_s': 0.1}}, False),
    ('robot_falling', 'shell_robot', {'actuation': {'distribution': 'falling'}}, False),
    ('robot_command', 'shell_robot', {}, True),
    ('robot_command_rated', 'shell_robot',
     {'actuation': {'source': 'command', 'max_cable_force_n': 5.0}}, False),
    ('robot_command_no_amplitude', 'shell_robot',
     {'actuation': {'source': 'command', 'amplitude': None}}, False),
    ('robot_starting_jet', 'shell_robot',
     {'jet': {'starting_jet': True, 'formation_number': 3.0}}, False),
    ('robot_terms_off', 'shell_robot',
     {'terms': {'viscosity': False, 'drag': False, 'added_mass': False},
      'vehicle': {'added_mass_kg': 0.05, 'initial_velocity_m_s': 0.1},
      'material': {'shear_correction': 0.8, 'rotary_inertia_scale': 2.0}}, False),
    ('robot_no_jet_section', 'shell_robot',
     {'terms': {'jet': False}, 'jet': None}, False),
    ('robot_defaults', 'shell_robot',
     {'fluid': {'added_mass_coefficient': None, 'tangential_drag_coefficient': None},
      'vehicle': None, 'jet': {'thrust_coefficient': None, 'inlet_area_m2': 2e-3},
      'simulation': {'newton_tolerance': None, 'duration_s': None,
                     'keep_newton_workspace': None, 'specialise_kernel': True}}, False),
    ('ellipsoid_added_mass_length', 'shell_ellipsoid',
     {'fluid': {'added_mass_length_m': 0.01}}, False),
]

# bad inputs: (name, scene, overrides)
BAD = [
    ('coupling_choice', 'shell_robot', {'coupling': 'loose'}),
    ('coupling_type', 'shell_robot', {'coupling': 3}),
    ('unknown_section', 'shell_robot', {'pump': {}}),
    ('sim_dt_zero', 'shell_robot', {'simulation': {'dt_s': 0.0}}),
    ('sim_dt_text', 'shell_robot', {'simulation': {'dt_s': 'fast'}}),
    ('sim_dt_bool', 'shell_robot', {'simulation': {'dt_s': True}}),
    ('sim_dt_missing', 'shell_robot', {'simulation': {'dt_s': None}}),
    ('sim_dt_nan', 'shell_robot', {'simulation': {'dt_s': float('nan')}}),
    ('sim_integrator', 'shell_robot', {'simulation': {'integrator': 'rk45'}}),
    ('sim_integrator_list', 'shell_robot', {'simulation': {'integrator': ['rk4']}}),
    ('sim_tolerance', 'shell_robot', {'simulation': {'newton_tolerance': 1e-3}}),
    ('sim_keep_text', 'shell_robot', {'simulation': {'keep_newton_workspace': 'yes'}}),
    ('sim_specialise_keep', 'shell_robot', {'simulation': {'specialise_kernel': True}}),
    ('sim_duration', 'shell_robot', {'simulation': {'duration_s': -1.0}}),
    ('sim_not_mapping', 'shell_robot', {'simulation': 3}),
    ('sim_verlet_paper', 'shell_cone',
     {'coupling': 'paper', 'simulation': {'integrator': 'verlet', 'dt_s': 1e-6}}),
    ('sim_verlet_unstable', 'shell_robot',
     {'simulation': {'integrator': 'verlet', 'dt_s': 1e-3}, 'actuation': {'kind': 'none'}}),
    ('sim_dt_routine', 'shell_robot', {'simulation': {'dt_s': 0.05}}),
    ('mesh_small', 'shell_robot', {'mesh': {'elements': 2}}),
    ('mesh_text', 'shell_robot', {'mesh': {'elements': 'many'}}),
    ('mesh_float', 'shell_robot', {'mesh': {'elements': 12.0}}),
    ('mesh_unknown', 'shell_robot', {'mesh': {'cells': 3}}),
    ('geometry_kind', 'shell_robot', {'geometry': {'kind': 'torus'}}),
    ('geometry_kind_list', 'shell_robot', {'geometry': {'kind': ['cone']}}),
    ('geometry_missing', 'shell_robot', {'geometry': None}),
    ('material_E', 'shell_robot', {'material': {'youngs_modulus_pa': -5.0}}),
    ('material_E_text', 'shell_robot', {'material': {'youngs_modulus_pa': 'soft'}}),
    ('material_nu', 'shell_robot', {'material': {'poisson_ratio': 0.5}}),
    ('material_thick', 'shell_robot', {'material': {'half_thickness_m': 0.02}}),
    ('material_unknown', 'shell_robot', {'material': {'colour': 'red'}}),
    ('material_rubber_with_poisson', 'shell_robot',
     {'material': {'law': 'neo_hookean', 'shear_modulus_pa': 1e4, 'youngs_modulus_pa': None}}),
    ('material_rubber_without_mu', 'shell_robot',
     {'material': {'law': 'neo_hookean', 'youngs_modulus_pa': None, 'poisson_ratio': None}}),
    ('material_missing_key', 'shell_robot', {'material': {'density_kg_m3': None}}),
    ('material_kappa', 'shell_robot', {'material': {'shear_correction': 2.0}}),
    ('terms_text', 'shell_robot', {'terms': {'jet': 'yes'}}),
    ('terms_unknown', 'shell_robot', {'terms': {'magic': True}}),
    ('fluid_rho', 'shell_robot', {'fluid': {'density_kg_m3': 0.5}}),
    ('fluid_unknown', 'shell_robot', {'fluid': {'salinity': 35}}),
    ('fluid_inertia', 'shell_robot', {'fluid': {'internal_inertia': 'slug'}}),
    ('fluid_inertia_ring', 'shell_robot', {'fluid': {'internal_inertia': 'one_dimensional'}}),
    ('fluid_momentum_text', 'shell_robot', {'fluid': {'internal_flow_momentum': 'yes'}}),
    ('fluid_momentum_alone', 'shell_robot', {'fluid': {'internal_flow_momentum': True}}),
    ('jet_outlet', 'shell_robot', {'jet': {'outlet': 'nozzle'}}),
    ('jet_radius_edge', 'shell_robot', {'jet': {'outlet': 'edge'}}),
    ('jet_radius_big', 'shell_robot', {'jet': {'outlet_radius_m': 0.05}}),
    ('jet_paper_code_ring', 'shell_cone',
     {'coupling': 'paper_code', 'jet': {'outlet': 'ring'}}),
    ('jet_unknown', 'shell_robot', {'jet': {'diameter_m': 0.02}}),
    ('jet_cf', 'shell_robot', {'jet': {'thrust_coefficient': 3}}),
    ('jet_starting_text', 'shell_robot', {'jet': {'starting_jet': 'yes'}}),
    ('jet_formation_off', 'shell_robot', {'jet': {'formation_number': 4.0}}),
    ('jet_formation_range', 'shell_robot',
     {'jet': {'starting_jet': True, 'formation_number': 0.1}}),
    ('jet_starting_paper', 'shell_cone', {'coupling': 'paper', 'jet': {'starting_jet': True}}),
    ('jet_missing', 'shell_robot', {'jet': None}),
    ('vehicle_light', 'shell_robot', {'vehicle': {'mass_kg': 0.01}}),
    ('vehicle_unknown', 'shell_robot', {'vehicle': {'colour': 'red'}}),
    ('vehicle_speed', 'shell_robot', {'vehicle': {'initial_velocity_m_s': 1000.0}}),
    ('actuation_kind', 'shell_robot', {'actuation': {'kind': 'pump'}}),
    ('actuation_source', 'shell_cone', {'actuation': {'source': 'command'}}),
    ('actuation_distribution', 'shell_robot', {'actuation': {'distribution': 'parabolic'}}),
    ('actuation_release', 'shell_robot', {'actuation': {'release_s': 0.6}}),
    ('actuation_sum', 'shell_robot', {'actuation': {'release_s': 0.5}}),
    ('actuation_unknown', 'shell_robot', {'actuation': {'taper_fraction': 0.1}}),
    ('actuation_amplitude', 'shell_robot', {'actuation': {'amplitude': 2000.0}}),
    ('actuation_amp_missing', 'shell_robot', {'actuation': {'amplitude': None}}),
    ('actuation_rating', 'shell_robot', {'actuation': {'max_cable_force_n': 0.0}}),
    ('actuation_freq', 'shell_robot', {'actuation': {'frequency_hz': 0}}),
    ('actuation_pulse', 'shell_robot', {'actuation': {'pulse': 'square'}}),
    ('actuation_muscle_amp', 'shell_cone', {'actuation': {'amplitude': 0.99}}),
    ('actuation_muscle_desired', 'shell_cone', {'actuation': {'desired_radius': 'wide'}}),
    ('actuation_not_mapping', 'shell_robot', {'actuation': 'cable'}),
    ('load_unknown', 'shell_robot', {'load': {'external_pressure_pa': 1.0}}),
    ('load_range', 'shell_robot', {'load': {'internal_pressure_pa': 1e7}}),
    ('initial_range', 'shell_robot', {'initial': {'radial_perturbation_m': 0.5}}),
    ('initial_unknown', 'shell_robot', {'initial': {'axial_perturbation_m': 0.5}}),
]


def _drop_none(data):
    """Return data with every None value removed (an override's way to delete a key)."""
    if isinstance(data, dict):
        return {k: _drop_none(v) for k, v in data.items() if v is not None}
    return data


def _scene(name, overrides, command_driven=False):
    """Load a scene with overrides whose None values delete the key."""
    raw = read_yaml_file(ROOT / 'config' / f'{name}.yaml')
    data = _drop_none(merge(copy.deepcopy(raw), overrides))
    for key, value in overrides.items():
        if value is None:
            data.pop(key, None)
    import tempfile

    import yaml

    path = Path(tempfile.gettempdir()) / f'shell_scene_bits_{name}.yaml'

    path.write_text(yaml.safe_dump(data))
    return load_scene(path, command_driven=command_driven)


def _sha(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def fingerprint(scene) -> dict:
    model = scene.model
    attrs = {
        'dt_s': model.dt_s, 'integrator': model.integrator, 'flags': model.flags,
        'actuation': model.actuation, 'material': model.material, 'coupling': model.coupling,
        'outlet': model.outlet, 'code_rim': model.code_rim,
        'isotropic_added_mass': model.isotropic_added_mass,
        'payload_kg': model.payload_kg, 'body_added_mass_kg': model.body_added_mass_kg,
        'initial_perturbation_m': model.initial_perturbation_m,
        'ring_added_mass_kg': model.ring_added_mass_kg,
        'initial_velocity_m_s': model.initial_velocity_m_s, 'duration_s': model.duration_s,
        'specialise_kernel': model.specialise_kernel,
        'keep_newton_workspace': model.keep_newton_workspace,
        'command_limits': model.command_limits, 'scene_duration_s': scene.duration_s,
        'publish_rate_hz': scene.publish_rate_hz, 'routine': scene.routine,
    }
    sim = Simulation(model)
    steps = min(MAX_STEPS, int(round(STEP_S / model.dt_s)))
    sim.step(steps)
    return {
        'P': _sha(model.P),
        'tables': _sha(model.E, model.Nd, model.node_mass, model.node_added_mass, model.n0,
                       model.am_blocks),
        'attributes': hashlib.sha256(repr(sorted(attrs.items())).encode()).hexdigest(),
        'steps': steps,
        'state': _sha(sim.state),
    }


def collect() -> dict:
    out = {'scenes': {}, 'errors': {}}
    for path in sorted((ROOT / 'config').glob('*.yaml')):
        if read_yaml_file(path).get('model') == 'shell':
            out['scenes'][f'config/{path.name}'] = fingerprint(load_scene(path.stem))
    for path in sorted((ROOT / 'validation' / 'cases').glob('*.yaml')):
        case = read_yaml_file(path)
        base = read_yaml_file(ROOT / 'config' / f'{case["scene"]}.yaml')
        if base.get('model') != 'shell':
            continue
        runs = [('', case.get('overrides') or {})]
        runs += [(f'probe {p["id"]}', merge(case.get('overrides') or {}, p['overrides']))
                 for p in case.get('probes') or ()]
        for label, overrides in runs:
            key = f'validation/{path.name} {label}'.strip()
            out['scenes'][key] = fingerprint(load_scene(case['scene'], overrides or None))
    for name, scene, overrides, command_driven in VARIANTS:
        out['scenes'][f'variant {name}'] = fingerprint(_scene(scene, overrides, command_driven))
    for name, scene, overrides in BAD:
        try:
            _scene(scene, overrides)
        except SceneError as err:
            out['errors'][name] = str(err)
        else:
            out['errors'][name] = '(accepted)'
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument('--write', type=Path)
    group.add_argument('--check', type=Path)
    args = parser.parse_args()
    now = collect()
    if args.write:
        args.write.write_text(json.dumps(now, indent=1, sort_keys=True) + '\n')
        print(f'wrote {args.write}: {len(now["scenes"])} scenes, {len(now["errors"])} refusals')
        return 0
    base = json.loads(args.check.read_text())
    same = [k for k in base['scenes'] if now['scenes'].get(k) == base['scenes'][k]]
    differ = sorted(set(base['scenes']) - set(same))
    print(f'{len(same)} of {len(base["scenes"])} scenes identical (P, tables, attributes, state)')
    for k in differ:
        print(f'  DIFFERS {k}: {base["scenes"][k]} -> {now["scenes"].get(k)}')
    changed = 0
    for k, text in base['errors'].items():
        if now['errors'].get(k) != text:
            changed += 1
            print(f'  refusal {k}:\n    before: {text}\n    after:  {now["errors"].get(k)}')
    print(f'{len(base["errors"]) - changed} of {len(base["errors"])} refusal texts unchanged')
    return 1 if differ else 0


if __name__ == '__main__':
    sys.exit(main())
