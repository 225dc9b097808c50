"""
Convergence of a shell validation case's figures: Richardson estimate, error estimate, check.

The rules are those of validation/convergence_plan.md (committed before the runs).  A shell's
stored figures (its scene's mesh, step and Newton tolerance) are compared with a converged
estimate from a mesh ladder N0, 2 N0, 4 N0 whose every mesh puts a node on each kink of the
geometry (on other meshes the kink's place inside its element adds an O(h) error of either sign,
so their differences are not a power series in the element size), run at a fine step (dt/8) and
a tight Newton tolerance (1e-9) so that neither the step's error nor the Newton iteration's
stopping noise enters the mesh differences.  The estimate is checked against 8 N0.  Beside it:
the step ladder at the stored mesh (dt .. dt/8), the stored Newton tolerance's part, and the
stored mesh doubled (the experiment that shows the kink's effect).

The element and the implicit midpoint step are both second order (docs/theory/shell.md:
work-equivalent nodal loads; test_shell_convergence), so the ladder is accepted as asymptotic when
its observed order is within 0.5 of 2.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

# Newton tolerance of every refinement run: the scene schema's default, far below the stored
# 1e-4 (whose stopping noise, ~1e-4 relative, is the size of the differences being measured)
STUDY_NEWTON_TOLERANCE = 1e-9
# the ladder's step is the stored step over this (a power of two: the 10 ms sample period stays a
# whole number of steps, so every level is sampled at the same instants)
STEP_DIVISOR = 8
# order of the discretisation (element and step), and how far an observed order may stray from
# it for a ladder to count as in its asymptotic range
FORMAL_ORDER = 2.0
ORDER_BAND = 0.5
# differences below this (relative) are taken as the 1e-9 tolerance's noise: no order is read
NOISE_RELATIVE = 1e-7
# Roache's grid convergence index safety factor with an observed order (Roache, Verification and
# Validation in Computational Science and Engineering, 1998, ch. 5)
GCI_FS = 1.25
# a node counts as on a kink when it is within this fraction of an element of it
KINK_SNAP = 0.015


def kink_fractions(geometry: Mapping[str, Any]) -> tuple[float, ...]:
    """
    Return the arc-length places (fractions of the meridian, pole = 0) of the geometry's kinks.

    ``cap_cylinder``: the cap/cylinder junction, at cap arc / (cap arc + cylinder length)
    (geometry._cap_cylinder).  Other kinds have no kink this module knows of: an empty tuple.
    """
    if not isinstance(geometry, Mapping) or geometry.get('kind') != 'cap_cylinder':
        return ()
    arc = float(geometry['cap_radius_m']) * float(geometry['cap_opening_rad'])
    return (arc / (arc + float(geometry['cylinder_length_m'])),)


def aligned_mesh(n_min: int, fractions: Sequence[float], n_max: int = 4096) -> int:
    """Smallest number of elements >= n_min with a node within KINK_SNAP elements of each kink."""
    for n in range(int(n_min), n_max + 1):
        if all(abs(n * f - round(n * f)) <= KINK_SNAP for f in fractions):
            return n
    raise ValueError(f'no mesh of {n_min}..{n_max} elements puts a node on the kinks {fractions}')


def observed_order(f1, f2, f3) -> tuple[float | None, str]:
    """
    Observed order of three levels refined by 2: (p, '') or (None, why there is none).

    ``p = log2(|f1 - f2| / |f2 - f3|)`` when both differences share a sign and exceed
    NOISE_RELATIVE of the value.
    """
    if None in (f1, f2, f3):
        return None, 'a level has no value'
    d1, d2 = f1 - f2, f2 - f3
    floor = NOISE_RELATIVE * max(abs(f3), 1e-300)
    if abs(d1) <= floor or abs(d2) <= floor:
        return None, f'differences below {NOISE_RELATIVE:g} relative'
    if d1 * d2 < 0:
        return None, 'differences of either sign'
    return math.log2(d1 / d2), ''


def asymptotic(p: float | None) -> bool:
    """Whether an observed order counts as the discretisation's (within ORDER_BAND of 2)."""
    return p is not None and abs(p - FORMAL_ORDER) <= ORDER_BAND


def richardson(f2: float, f3: float, p: float) -> float:
    """Richardson extrapolation of the last two levels (refined by 2) with order p."""
    return f3 + (f3 - f2) / (2.0 ** p - 1.0)


def converged_figure(
    ladder: Sequence, check, step_pair: Sequence, stored, step_ladder: Sequence,
) -> dict:
    """
    One figure's converged estimate, error estimate, check and the stored value's error parts.

    ``ladder``: the figure at N0, 2 N0, 4 N0 (step dt/8, tolerance 1e-9); ``check``: at 8 N0;
    ``step_pair``: at 2 N0 with steps dt/4 and dt/8; ``stored``: the stored figure;
    ``step_ladder``: at the stored mesh, steps dt, dt/2, dt/4, dt/8 (tolerance 1e-9).
    """
    f1, f2, f3 = ladder
    p, why = observed_order(f1, f2, f3)
    p_fine, why_fine = observed_order(f2, f3, check)
    t_err = abs(step_pair[0] - step_pair[1]) / 3.0 if None not in step_pair else 0.0
    out: dict[str, Any] = {
        'ladder': list(ladder),
        'check': check,
        'order': p,
        'order_why': why,
        'order_fine': p_fine,
        'order_fine_why': why_fine,
        'step_error': t_err,
    }
    if None in (f1, f2, f3, check):
        out.update(converged=None, estimate=None, how='a run has no value', check_ok=False)
        return out
    if asymptotic(p):
        value = richardson(f2, f3, p)
        estimate = GCI_FS * abs(f3 - value) + t_err
        how = 'Richardson'
    else:
        value = check
        estimate = max(abs(f2 - f3), abs(f3 - check)) + t_err
        reason = why or f'order {p:.2f} not within {ORDER_BAND:g} of {FORMAL_ORDER:g}'
        how = f'check run (ladder not asymptotic: {reason})'
    out.update(
        converged=value,
        estimate=estimate,
        estimate_rel=estimate / abs(value),
        how=how,
        # with no asymptotic order the estimate is the check run itself: no independent check
        check_ok=abs(check - value) <= estimate if how == 'Richardson' else None,
        check_rel=(check - value) / value,
    )
    # the stored value's error and its parts: Newton tolerance (stored against the same mesh and
    # step at 1e-9), step (at the stored mesh, against its step ladder's Richardson estimate), mesh
    # (the rest: the stored mesh's converged-in-time value against the converged estimate)
    g1, g2, g3, g4 = step_ladder
    if stored is not None and None not in step_ladder:
        pt, why_t = observed_order(g1, g2, g3)
        pt_fine, why_t_fine = observed_order(g2, g3, g4)
        g_inf = richardson(g3, g4, pt_fine) if asymptotic(pt_fine) else g4
        out.update(
            stored=stored,
            stored_error_rel=(stored - value) / value,
            tolerance_part_rel=(stored - g1) / value,
            step_part_rel=(g1 - g_inf) / value,
            mesh_part_rel=(g_inf - value) / value,
            step_order=pt,
            step_order_why=why_t,
            step_order_fine=pt_fine,
            step_order_fine_why=why_t_fine,
        )
    return out


def shell_convergence(
    mesh_elements: int,
    dt_s: float,
    geometry: Mapping[str, Any],
    stored: Mapping[str, float | None],
    figures_at: Callable[[dict], tuple[dict, str | None]],
) -> dict:
    """
    Run the ladders of validation/convergence_plan.md for a shell case and estimate each figure.

    ``figures_at(overrides)`` runs the case with the scene overrides and returns (figures,
    fault).  ``stored``: the stored figures (the case's own run).
    """
    fractions = kink_fractions(geometry)
    n0 = aligned_mesh(mesh_elements, fractions) if fractions else 2 * mesh_elements
    fine_dt = dt_s / STEP_DIVISOR
    tol = STUDY_NEWTON_TOLERANCE

    def run(elements: int, step: float) -> dict:
        figures, fault = figures_at(
            {
                'mesh': {'elements': elements},
                'simulation': {'dt_s': step, 'newton_tolerance': tol},
            }
        )
        return {'elements': elements, 'dt_s': step, 'fault': fault, 'figures': figures}

    mesh_runs = [run(n0 * k, fine_dt) for k in (1, 2, 4, 8)]
    step_runs = [run(mesh_elements, dt_s / k) for k in (1, 2, 4, 8)]
    step_check = run(2 * n0, 2 * fine_dt)
    doubled = [run(mesh_elements * k, fine_dt) for k in (1, 2, 4)]
    out_figures = {}
    for name, value in stored.items():
        def at(runs, key=name):
            return [r['figures'].get(key) for r in runs]

        entry = converged_figure(
            at(mesh_runs[:3]),
            mesh_runs[3]['figures'].get(name),
            (step_check['figures'].get(name), mesh_runs[1]['figures'].get(name)),
            value,
            at(step_runs),
        )
        d_order, d_why = observed_order(*at(doubled))
        entry['doubled'] = at(doubled)
        entry['doubled_order'] = d_order
        entry['doubled_order_why'] = d_why
        out_figures[name] = entry
    return {
        'kink_fractions': list(fractions),
        'kink_place_in_element': {
            str(n): [n * f - math.floor(n * f) for f in fractions]
            for n in (mesh_elements, 2 * mesh_elements, 4 * mesh_elements, n0)
        },
        'newton_tolerance': tol,
        'ladder_dt_s': fine_dt,
        'mesh_ladder': mesh_runs,
        'step_ladder': step_runs,
        'step_check': step_check,
        'doubled_stored_mesh': doubled,
        'figures': out_figures,
    }
