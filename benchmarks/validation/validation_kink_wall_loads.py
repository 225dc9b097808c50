"""
Numerical experiment (not the validation): the cable robot's mesh order before and after issue 23.

`pulsejet validate` refines each shell case on meshes that put a node on the cap/cylinder kink
(36, 72, 144, checked against 288 elements; validation/convergence_plan.md). Before issue 23's
item 1 the volume converged there at the element's second order but the speeds did not (observed
orders -0.51 to 0.48): two wall loads were nodal and took one direction over the node's whole
area, which spans both sides of the kink. The added mass was a nodal block ``m_a n0 n0^T`` along
the node's reference normal, interpolated between the cap's and the cylinder's at the kink node;
the tangential drag ``-1/2 rho C_t A_i |v_t| v_t`` acted along the node's rotation; and the
clamped ring's half element took neither load. An earlier run of this experiment (commit d3696d3)
patched the kink node's added mass into its two sides' normals and switched the tangential drag
off: every speed then converged at order 2.10-2.15.

Since issue 23 item 1 the model applies both loads element by element (docs/theory/shell.md,
wall loads). This table puts the stored ladders side by side: before, the "as coded" ladders of
docs/validation/results.json at commit d3696d3 (the same settings; the values below), and after,
the same file as `pulsejet validate` writes it now. No run of its own. Writes
benchmarks/results/validation_kink_wall_loads.md.

    .venv/bin/python -m benchmarks.validation.validation_kink_wall_loads
"""

from __future__ import annotations

import json
import sys

from benchmarks import common
from pulsejet_sim.studies import validation as V
from pulsejet_sim.studies.validation_convergence import observed_order

SHELL_CASES = (
    'cable_robot_from_rest',
    'cable_robot_from_rest_starting_jet',
    'cable_robot_steady',
    'cable_robot_steady_starting_jet',
)

#: the ladders 36 / 72 / 144 / 288 of docs/validation/results.json at commit d3696d3 (nodal wall
#: loads, before issue 23 item 1)
BEFORE = {
    'cable_robot_from_rest': {
        'mean_speed': (
            0.06986671636253153, 0.0698476254379789,
            0.0698291786533109, 0.069814418437357,
        ),
        'burst_speed': (
            0.09480538298402956, 0.09479588723256543,
            0.09478232271002052, 0.09476960562547938,
        ),
    },
    'cable_robot_from_rest_starting_jet': {
        'mean_speed': (
            0.07948874854235806, 0.07945985636511654,
            0.07943684946000826, 0.07941998368668293,
        ),
        'burst_speed': (
            0.1064950909041508, 0.10647599018542735,
            0.10645808030198638, 0.1064434030388698,
        ),
    },
    'cable_robot_steady': {
        'mean_speed': (
            0.0855890605385797, 0.08556746594194253,
            0.08554900504645344, 0.08553456244721795,
        ),
        'burst_speed': (
            0.09506306159391022, 0.09505348765018715,
            0.09504002867221525, 0.09502741259367138,
        ),
        'stroke_volume': (
            3.563592267142969e-05, 3.5653918892509005e-05,
            3.565830392584577e-05, 3.56581155358162e-05,
        ),
    },
    'cable_robot_steady_starting_jet': {
        'mean_speed': (
            0.09564621399345316, 0.09561431756841188,
            0.09559111164802081, 0.09557452473328984,
        ),
        'burst_speed': (
            0.10665594496299707, 0.10663692197949405,
            0.106619202028878, 0.10660468875907951,
        ),
        'stroke_volume': (
            3.421645466264423e-05, 3.423364162300093e-05,
            3.423780993929511e-05, 3.423744831860734e-05,
        ),
    },
}


def ladder_text(values) -> str:
    orders = [observed_order(*values[i:i + 3]) for i in range(len(values) - 2)]
    cells = ' / '.join(f'{v:.7g}' for v in values)
    return cells + ' | ' + ', '.join(
        f'{p:.2f}' if p is not None else f'none ({why})' for p, why in orders
    )


def main() -> int:
    stored = json.loads((V.OUT_DIR / 'results.json').read_text())['cases']
    lines = [
        common.header(
            "Validation: the cable robot's mesh order before and after the element-wise wall "
            'loads',
            'python -m benchmarks.validation.validation_kink_wall_loads',
        ).rstrip('\n'),
        '',
        'Each shell case of `pulsejet validate` on its kink-aligned ladder 36/72/144/288 (step '
        'and Newton tolerance as the validation report). Before: the nodal added mass and '
        "tangential drag (one direction over the node's whole area; the ring's half element "
        'without either), the ladders of docs/validation/results.json at commit d3696d3. After: '
        'both loads element by element (issue 23 item 1), the same file as written now. Orders: '
        'log2 of the ratio of consecutive differences over 36/72/144 and 72/144/288.',
        '',
        '| case | figure | wall loads | 36 / 72 / 144 / 288 | orders |',
        '|---|---|---|---|---|',
    ]
    for case_id in SHELL_CASES:
        conv = stored[case_id]['convergence']
        for name, entry in conv['figures'].items():
            after = entry['ladder'] + [entry['check']]
            lines.append(f'| {case_id} | {name} | before: nodal | '
                         f'{ladder_text(BEFORE[case_id][name])} |')
            lines.append(f'| | | after: element by element | {ladder_text(after)} |')
    common.write('validation_kink_wall_loads', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
