"""
Numerical experiment (not the validation): why the cable robot's speeds show no mesh order.

`pulsejet validate` refines each shell case on meshes that put a node on the cap/cylinder kink
(36, 72, 144, checked against 288 elements; validation/convergence_plan.md). The volume converges
there at the element's second order, but the speeds do not: their differences stay about the same
at every doubling (observed orders near 0). The shell's added mass is a nodal block
``m_a n0 n0^T`` along the node's reference normal (models/shell/model.py, ``_node_masses``), and
the reference normal of the node on the kink is interpolated between the cap's and the cylinder's
(geometry.build_reference_meridian): a normal that neither side has, on a node area of O(h). That
is an O(h) error in the water's inertia, the term that couples the wall's radial motion to the
vehicle's axial motion.

The tangential drag has the same form: ``-1/2 rho C_t A_i |v_t| v_t`` along the node's current
rotation (kernels.py), one direction over a node area that spans both sides of the kink.

The experiment reruns the same ladder (1) with the kink node's added-mass block split into its
two halves, each with its own side's normal, ``m_a/A (A_cap/2 n_cap n_cap^T + A_cyl/2 n_cyl
n_cyl^T)`` (on a smooth wall the two halves coincide with the node's block), patched into the
built model's node table; (2) with the tangential drag off (``fluid.tangential_drag_coefficient:
0``, an experiment that changes the physics, not a proposal); (3) both. No scene value and no
model code changes. The as-coded ladder is read from docs/validation/results.json (same runs,
same settings). Writes benchmarks/results/validation_kink_wall_loads.md.

    .venv/bin/python -m benchmarks.validation.validation_kink_wall_loads
"""

from __future__ import annotations

import json
import math
import sys

from benchmarks import common
import numpy as np
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.studies import validation as V
from pulsejet_sim.studies.validation_convergence import kink_fractions, observed_order

SHELL_CASES = (
    'cable_robot_from_rest',
    'cable_robot_from_rest_starting_jet',
    'cable_robot_steady',
    'cable_robot_steady_starting_jet',
)


def split_kink_added_mass(scene) -> int:
    """Give the kink node's added mass each side's normal on its half area; return the node."""
    geometry = scene.data['geometry']
    model = scene.model
    Nd, E = model.Nd, model.E
    n = E.shape[0]
    k = int(round(n * kink_fractions(geometry)[0]))
    alpha = float(geometry['cap_opening_rad'])
    # reference normal n0 = (-sin theta, cos theta), theta the tangent angle from the pole: the
    # cap ends at theta = -alpha, the cylinder runs at theta = -pi/2
    n_cap = np.array([math.sin(alpha), math.cos(alpha)])
    n_cyl = np.array([1.0, 0.0])
    a_cap, a_cyl = 0.5 * E[k - 1, sk.E_AREA], 0.5 * E[k, sk.E_AREA]
    per_area = float(model.node_added_mass[k]) / (a_cap + a_cyl)
    block = per_area * (a_cap * np.outer(n_cap, n_cap) + a_cyl * np.outer(n_cyl, n_cyl))
    m = float(model.node_mass[k])
    Nd[k, sk.N_MRR] = m + block[0, 0]
    Nd[k, sk.N_MRZ] = block[0, 1]
    Nd[k, sk.N_MZZ] = m + block[1, 1]
    return k


def ladder_text(values) -> str:
    orders = [observed_order(*values[i:i + 3]) for i in range(len(values) - 2)]
    cells = ' / '.join(f'{v:.7g}' for v in values)
    return cells + ' | ' + ', '.join(
        f'{p:.2f}' if p is not None else f'none ({why})' for p, why in orders
    )


# the variants: (label, scene overrides, split the kink node's added mass)
NO_TANGENTIAL_DRAG = {'fluid': {'tangential_drag_coefficient': 0.0}}
VARIANTS = (
    ("kink node's added mass split", {}, True),
    ('no tangential drag (C_t = 0)', NO_TANGENTIAL_DRAG, False),
    ('both', NO_TANGENTIAL_DRAG, True),
)


def run_figures(case: dict, elements: int, dt_s: float, tol: float, extra: dict,
                split: bool) -> dict:
    """Return the case's figures at one mesh, step and Newton tolerance, in one variant."""
    scene = V._scene(
        case,
        V.merge(
            extra,
            {'mesh': {'elements': elements},
             'simulation': {'dt_s': dt_s, 'newton_tolerance': tol}},
        ),
    )
    if split:
        split_kink_added_mass(scene)
    run = case['run']
    trace = V.run_trace(scene, float(run['duration_s']), float(run['sample_period_s']))
    print(case['id'], elements, extra, split, file=sys.stderr, flush=True)
    return V.figures_of(case, trace)[0]


def main() -> int:
    stored = json.loads((V.OUT_DIR / 'results.json').read_text())['cases']
    lines = [
        common.header(
            "Validation: the kink node's wall loads and the cable robot's mesh order",
            'python -m benchmarks.validation.validation_kink_wall_loads',
        ).rstrip('\n'),
        '',
        'Each shell case of `pulsejet validate` on its kink-aligned ladder 36/72/144/288 (step '
        'and Newton tolerance as the validation report): as coded (from '
        "docs/validation/results.json, the same runs), with the kink node's added mass split "
        "between its two sides' normals, with the tangential drag off (the other nodal wall load "
        "that uses one direction, the node's rotation, over the node's whole area), and both. "
        'Orders: log2 of the ratio of consecutive differences over 36/72/144 and 72/144/288. '
        'The variants are experiments: they change the physics (C_t = 0) or patch the built '
        "model's node table (split); no scene value and no model code changes.",
        '',
        '| case | figure | variant | 36 / 72 / 144 / 288 | orders |',
        '|---|---|---|---|---|',
    ]
    for case_id in SHELL_CASES:
        case = V.load_case(V.CASES_DIR / f'{case_id}.yaml')
        conv = stored[case_id]['convergence']
        dt, tol = conv['ladder_dt_s'], conv['newton_tolerance']
        ladder = [level['elements'] for level in conv['mesh_ladder']]
        runs = {
            label: [run_figures(case, n, dt, tol, extra, split) for n in ladder]
            for label, extra, split in VARIANTS
        }
        for name, entry in conv['figures'].items():
            coded = entry['ladder'] + [entry['check']]
            lines.append(f'| {case_id} | {name} | as coded | {ladder_text(coded)} |')
            for label, values in runs.items():
                lines.append(
                    f'| | | {label} | {ladder_text([v[name] for v in values])} |'
                )
    common.write('validation_kink_wall_loads', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
