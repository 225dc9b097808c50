"""
Geometrically exact axisymmetric (Reissner) shell model of the mantle (paper 000).

The mantle is coupled to a jet.

Model
-----
*Shell.*  The meridian (reference arc length X from the pole to the ring, see shell/geometry.py)
is cut into N equal elements; every node carries ``(r, z, theta)``; strains, the Kelvin-Voigt law
(half-thickness h, ``Psi = 2Eh/(1-nu^2)``, ``Psi2 = 6 eta_v h/(1-nu^2)``, ``Js = h^2/3``,
``q = 2hG eta + 2h eta_v eta_dot``) and their discrete energy/dissipation are documented in
shell/kernels.py.  Internal forces are exact gradients of the discrete elastic energy, the viscous
ones come from a dissipation function, so the scheme conserves energy by construction when the
viscosity and the fluid loads are off (tested).  ``material.law: neo_hookean`` makes the membrane
part an incompressible neo-Hookean sheet's (E = 3 mu, nu = 1/2 elsewhere; the muscle an active
strain): docs/theory/shell_rubber.md.

*Boundary conditions.*  Pole (node 0): ``r = 0`` and ``theta = theta0(0)`` (0 for a smooth pole),
``z`` free.  Ring (node N): clamped to the rigid cap/nozzle, which is part of the vehicle.

*Masses.*  Lumped: ``m_i = rho_s 2h A_i`` (A_i the node's share of the reference area
``2 pi r0 dX``), rotary inertia ``m_i h^2/3`` (times ``material.rotary_inertia_scale``).
Fluid added mass acts along the surface normal, element by element: ``C_a rho l_a`` per area
(l_a = ``fluid.added_mass_length_m``, default half the largest radius, i.e. the 2-D added mass per
unit area ``rho a/2`` of a cylinder of radius a, times C_a = 1.1) along each element's *reference*
normal ``n_e``; each node's block sums its element halves' ``C_a rho l_a A_e/2 n_e n_e^T``
(``added_mass_blocks``), so the node on a kink keeps each side's normal.  Using reference normals
keeps the mass matrix constant and the added-mass force conservative; it is approximate when the
wall rotates a lot.  The clamped ring's half moves axially with the vehicle: its axial added mass
is the vehicle's (consistent coupling).

*Frames.*  Positions are relative to the body; the axial node velocity is stored absolute
(``w = z_dot + U``), which makes the mass matrix block diagonal.  The shell therefore feels the
vehicle's motion exactly (its inertia, added mass and tangential drag see the absolute velocity,
the "vehicle speed enters the shell's loads"), and the vehicle feels the shell only through the
force at the clamped ring, the jet thrust and the inflow ram force.

*Fluid and jet.*  Cavity volume ``V`` = sum of frusta between the shell and the ring plane (the
rigid cap's own volume is not counted), ``V' = grad V . q_dot``.  Outflow (V' < 0) through
``A_out`` (``jet.contraction_coefficient`` Cc times the fixed outlet's area: a sharp-edged
exit's vena contracta): ``u_j = -V'/A_out``, cavity pressure ``p = rho u_j^2/2`` acting on the
inner surface (generalised force ``p grad V``; so the wall pays the jet's kinetic energy), thrust
``C_f rho A_out u_j^2`` on the vehicle.  Inflow through ``A_in``: suction ``p = -rho u_in^2/2`` and
the ram force ``rho V' U`` of bringing the ingested water to the vehicle speed.  The internal
water ``rho V`` moves with the vehicle.  Vehicle: ``(M + m_x + rho V) U' = T - 1/2 C_d rho
pi max(r)^2 |U| U - ram + F_ring``.  Tangential drag on the shell, element by
element: each element half ``-1/2 rho C_t A_e/2 |v_t| v_t`` along the element's current chord, on
its node (the clamped ring's half through the ring's reaction, on the vehicle).

*Couplings* (scene key ``coupling``; docs/theory/shell.md has the citations).  ``consistent``
(default): as described above.  ``paper``: paper 000's scheme (its coupling of Fig. 5): the shell
is solved in the body frame (its drag and added mass see only its own motion relative to the body),
the water loads the wall only through drag and added mass (no cavity pressure), and the vehicle
``(M + m_x + rho V) U' = T - D - ram`` is driven by the thrust of the shell's volume rate; the
vehicle velocity enters only the position update.  Its ledger books the jet's kinetic energy flux
``1/2 rho A |u_j|^3``, which no wall force pays for in that scheme, as
``created_unpaid_jet_kinetic``.
``jet.outlet``: ``ring`` (a fixed outlet of ``outlet_radius_m`` in the clamped ring; the consistent
default), ``edge`` (the paper default: the mantle's free edge is the nozzle, radius and angle free
at that edge, ``A_out = pi r_edge(t)^2``) or ``free_edge_fixed_nozzle`` (the edge free as with
``edge``, but the jet leaves through a fixed nozzle of ``outlet_radius_m``, ``A_out = pi r_n^2``:
the authors' later code, ``Area_out = pi*Rn.^2`` with ``Rn = 12.5e-3``, whose exit area does not
follow the shell).
``paper_code`` (the authors' public code as written, for auditing it; citations in
docs/validation/papers.md): the pole is clamped to the body and the edge is free in r,
z and theta; fixed nozzle (``free_edge_fixed_nozzle``, default radius 12.5 mm); no cavity pressure
and no tangential drag on the wall; thrust, a refilling force ``-C_f rho V'^2/A_in`` and the body
drag act on the wall as a uniform axial load per reference area and reach the vehicle through the
pole's reaction; added mass ``C_a`` times the node's own mass in r and z; the consistent coupling's
frame (the shell's inertia sees the vehicle's acceleration).  Its ledger books
``created_unpaid_jet_kinetic`` and ``created_wall_loads``.

*Energy ledger.*  Stored: elastic, shell + payload kinetic ("vehicle"), added-mass kinetic
("outer fluid"), ``1/2 rho V U^2`` ("internal").  In: actuation work (cable force times wall
velocity, plus ``dW/dt`` of the muscle's moving reference) is reported under ``in_actuation_work``
(the only "in" key of the contract).  Out: jet kinetic energy in the earth frame, drag (shell
and vehicle), Kelvin-Voigt dissipation, and ``out_other`` = inflow mixing (suction kinetic energy
and ram loss) + the thrust mismatch ``(1 - C_f) rho A u_j^2 U``.  With C_f = 1 all energy
transfers are exact in the continuous model, so ``closure_error`` measures time discretisation
only.

*Water inside* (``fluid.internal_inertia: one_dimensional``, docs/theory/shell.md, the water
inside). Kinetic energy ``1/2 rho Lambda V'^2`` of paper 001's one-dimensional internal flow,
``Lambda`` the reference cavity's inertance (``ReferenceMeridian.internal_inertance_per_m``); by
Lagrange's equation a uniform pressure ``-rho Lambda V''`` on the inner wall, stored in the ledger
as ``stored_kinetic_internal_flow``. ``one_dimensional_deforming`` takes ``Lambda`` of the current
shape (``shell.kernels.inertance``): the pressure becomes ``-rho (Lambda V')'`` and the wall also
feels ``+1/2 rho V'^2 grad Lambda``, Bernoulli's ``-1/2 rho u^2``, which pulls a narrow section
narrower while the water flows; a step that folds the meridian back along the axis stops the run
(the 1-D flow is undefined there). ``fluid.internal_flow_momentum: true`` (with ``one_dimensional``
only) adds the same flow's momentum relative to the body, ``rho S V'`` along +z (``S = int V_b/V
dz``, ``ReferenceMeridian.internal_momentum_length_m``): the vehicle feels ``-rho S V''``; in the
consistent coupling the wall also feels the uniform pressure ``-rho S U'`` (Lagrange's equation of
the cross term ``rho S U V'``, stored as ``stored_kinetic_internal_cross``); in the paper coupling
the wall's body frame has no such force and the ledger books the vehicle force's work as
``created_unpaid_internal_momentum``.

*Axis contact.*  A deeply collapsed wall meets the opposite wall on the axis: below the contact
radius ``min(h, r0/2)`` a conservative barrier (modulus E over the gap, log-barrier with a linear
continuation) keeps the midsurface off the axis; its energy is part of ``stored_elastic``.  This
lets > 80 % volume changes and soft (1 kPa) mantles run instead of crossing the axis.

*Integrators* (``simulation.integrator``).  ``verlet``: explicit kick-drift-kick; its stable
step (``stable_step_s``, from the generalised eigenvalues of stiffness and damping against the
mass) is tiny for the Kelvin-Voigt viscosity of the robot (~1.3 us), so scenes above it are
refused.  ``implicit_midpoint`` (default, 2nd order, energy conserving up to the nonlinearity)
and ``backward_euler`` (1st order, L-stable, numerically dissipative: its ledger does not close
at large steps) solve ``M (v* - v_n)/alpha = dt F(q_n + alpha dt v*, v*)`` by (modified) Newton
with a banded Jacobian (half bandwidth 5; element stiffness by forward differences, viscous and
drag damping exact) re-used across steps while it converges fast, plus a Sherman-Morrison
correction for the rank-one jet-pressure term.  The vehicle speed is solved monolithically with
the shell: it takes the slot of the clamped ring's axial dof, and by translation invariance
``dF/dU* = alpha dt K[:, ring_z] + C[:, ring_z]``, so the system stays banded (a staggered
vehicle update was unstable with stiff viscous walls).  A step whose Newton solve fails is
retried as 4, 16, 64 sub-steps before SimulationBlowUp is raised.

Scene keys (``model: shell``; see config/shell_robot.yaml): every key of every section is declared
once, with its rule, unit, range, default and meaning, in ``shell/scene_keys.py``; the tables of
docs/user/reference.md are generated from there. ``from_scene`` reads the scene section by section
(``_read_*`` below), each reader returning its part of the parameter vector P.

The cable routine: activation ``a(t)`` rises as a half cosine (``pulse: triangle``: a straight
line) over ``contraction_s``, falls over ``release_s`` and rests for the rest of the period; the
cable pull is ``amplitude * a(t)``, a line load along the meridian whose density is uniform,
proportional to X/L (``rising``: largest at the ring) or to 1 - X/L (``falling``: largest at the
pole); every node takes its work-equivalent (consistent) share ``int f N_i dX`` and the held ends'
shares go to the supports (``consistent_line_load``), so the nodal loads have the continuous
load's total and first moment at any mesh and the mesh error is second order.

*The other distributed loads, checked the same way.*  The muscle acts through each element's
desired hoop stretch inside the element energy (one-point quadrature like the elastic terms: no
nodal lumping).  The cavity pressure is ``p grad V`` of the discrete volume, its exact work
conjugate.  The added mass and the tangential drag act element by element: each element half
(``A_e/2``, ``A_e = 2 pi r0_m ds``) with the element's own direction (reference normal, current
chord), a row-sum quadrature of ``int f N_i dA`` whose shares differ from the exact
``2 pi ds (2 r_i + r_j)/6`` by O(ds^2) relative and sum to the exact area, second order like the
elements, also at a kink (docs/theory/shell.md, wall loads).  ``paper_code``'s wall-borne axial
load takes the exact consistent shares of the wall from the rim on (``consistent_area_shares``).

The muscle routine lowers the
desired hoop stretch to ``tau_d = 1 - amplitude a(t) s(X)`` (``s`` = 1 with smooth tapers at the
ends, at the pole only for ``constant_depth_to_edge``); the work it does is ``dW/dt`` at fixed
shape.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError, Observation, SimulationBlowUp
from pulsejet_sim.models.rubber import neo_hookean_shear_modulus_pa, refuse_keys_of_other_laws
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell import scene_keys as keys
from pulsejet_sim.models.shell.geometry import build_reference_meridian, ReferenceMeridian

_KERNELS: dict = {}
INTEGRATORS = {'verlet': (0, 1.0), 'implicit_midpoint': (1, 0.5), 'backward_euler': (1, 1.0)}
TERMS = {name: key.rule.default for name, key in keys.TERMS_SPEC.items()}
#: the reference profile is resampled this finely for the internal inertance, so that it does
#: not change with the mesh
DENSE_ELEMENTS = 4000
#: the routine's rise and fall (scene_keys.PULSE_NAMES) as the kernels code them
PULSE_SHAPES = {'half_cosine': sk.PULSE_HALF_COSINE, 'triangle': sk.PULSE_TRIANGLE}
ERR_TEXT = {
    sk.ERR_NONFINITE: 'non-finite state (NaN/inf)',
    sk.ERR_AXIS: 'the mantle wall crossed the symmetry axis (r < 0): the collapse is too deep for '
    'this shell; reduce the actuation amplitude',
    sk.ERR_BOUNDS: 'state out of bounds (a node or its speed ran away)',
    sk.ERR_NEWTON: 'the implicit Newton solve did not converge even with 64 sub-steps; '
    'use a smaller dt_s',
    sk.ERR_FOLD: 'the mantle folded back along the axis (an element reached zero axial extent): '
    'the one-dimensional internal flow of fluid.internal_inertia: one_dimensional_deforming is '
    'undefined there; use internal_inertia: one_dimensional or none',
}
#: entries of the parameter vector P (kernels' P_* slots) that one section of the scene fills
Part = dict[int, float]


def starting_jet_setting(jet, coupling, integrator, jet_on):
    """
    Return the formation number of ``jet.starting_jet`` (models/starting_jet.py), 0 when off.

    ``starting_jet: true`` adds the forming vortex ring's exit over-pressure; ``formation_number``
    (default 4, Gharib, Rambod & Shariff 1998) ends it at pinch-off.  The over-pressure must be
    paid by the cavity wall and enters the implicit solve as an inertia, so the term needs the
    consistent coupling and an implicit integrator.
    """
    if not keys.read(jet, 'jet', 'starting_jet', keys.JET_SPEC):
        if 'formation_number' in jet:
            raise ModelError(
                f'jet.formation_number: {jet["formation_number"]!r} is not used without '
                'jet.starting_jet: true; allowed: leave it out, or starting_jet: true'
            )
        return 0.0
    if coupling != 'consistent' or integrator == 'verlet' or not jet_on:
        raise ModelError(
            f'jet.starting_jet: true is not available with coupling: {coupling}, integrator: '
            f'{integrator}, terms.jet: {str(jet_on).lower()}; allowed: coupling consistent (the '
            'cavity wall pays the over-pressure), an implicit integrator (the forming ring is an '
            'inertia) and the jet on (or starting_jet: false)'
        )
    return keys.read(jet, 'jet', 'formation_number', keys.JET_SPEC)


def _read_coupling(scene: Any) -> str:
    """Check the scene's top level (its sections, its model) and return its coupling."""
    if not isinstance(scene, Mapping):
        raise ModelError(f'scene: {scene!r} is not a mapping')
    for k in scene:
        if k not in keys.SECTIONS:
            raise ModelError(
                f'{k}: unknown section for the shell model (value {scene[k]!r}); allowed: '
                f'{", ".join(keys.SECTIONS)}'
            )
    if scene.get('model', 'shell') != 'shell':
        raise ModelError(
            f'model: {scene.get("model")!r} is not the shell model; allowed: shell'
        )
    return keys.read(scene, '', 'coupling', keys.TOP_SPEC)


def _read_integrator(scene: Mapping[str, Any], coupling: str) -> tuple[dict, Part]:
    """Return the ``simulation`` section's time step, integrator and Newton solve settings."""
    sim = keys.section(scene, 'simulation')
    keys.refuse_unknown(sim, 'simulation', keys.SIMULATION_SPEC)

    def value(name):
        return keys.read(sim, 'simulation', name, keys.SIMULATION_SPEC)

    out = {'dt_s': value('dt_s'), 'integrator': value('integrator')}
    if coupling in ('paper', 'paper_code') and out['integrator'] == 'verlet':
        raise ModelError(
            f"simulation.integrator: 'verlet' is not available with coupling: {coupling}; "
            'allowed: implicit_midpoint or backward_euler'
        )
    for name in ('duration_s', 'newton_tolerance', 'specialise_kernel', 'keep_newton_workspace'):
        out[name] = value(name)
    if out['keep_newton_workspace'] and out['specialise_kernel']:
        raise ModelError(
            'simulation.keep_newton_workspace: true is not available with '
            'specialise_kernel: true (the kept workspace runs the generic kernel); '
            'allowed: specialise_kernel: false, or keep_newton_workspace: false'
        )
    part = {
        sk.P_DT: out['dt_s'],
        sk.P_ALPHA: INTEGRATORS[out['integrator']][1],
        sk.P_TOL: out['newton_tolerance'],
        sk.P_MAXIT: 30,
    }
    return out, part


def _read_geometry_and_mesh(scene: Mapping[str, Any]) -> tuple[Mapping, ReferenceMeridian, Part]:
    """Return the ``geometry`` mapping and its reference meridian on the ``mesh``'s elements."""
    mesh = keys.section(scene, 'mesh')
    keys.refuse_unknown(mesh, 'mesh', keys.MESH_SPEC)
    elements = keys.read(mesh, 'mesh', 'elements', keys.MESH_SPEC)
    geo = keys.section(scene, 'geometry')
    # before build_reference_meridian: a list is unhashable there
    keys.read(geo, 'geometry', 'kind', keys.GEOMETRY_KIND_SPEC)
    meridian = build_reference_meridian(geo, elements)
    rmax0 = float(meridian.r0.max())
    part = {
        sk.P_V0: meridian.volume_m3(),
        sk.P_QLIM: 20.0 * max(meridian.length_m, rmax0),
        sk.P_VLIM: 1000.0,
    }
    return geo, meridian, part


def _read_material(scene: Mapping[str, Any], rmax0: float) -> tuple[dict, Part]:
    """
    Return the wall's ``material`` and its stiffness, viscosity and contact.

    ``law: linear`` (Kelvin-Voigt on the Reissner strains, E and nu) or ``neo_hookean`` (mu from
    ``silicone`` or ``shear_modulus_pa``, models/rubber.py; E = 3 mu and nu = 1/2 for the rest).
    """
    mat = keys.section(scene, 'material')
    keys.refuse_unknown(mat, 'material', keys.MATERIAL_SPEC)
    law = keys.read(mat, 'material', 'law', keys.MATERIAL_SPEC)
    refuse_keys_of_other_laws(mat, law, keys.MATERIAL_LAW_KEYS)
    # the keys every law reads, and the linear law's own (neo_hookean's are read below)
    law_keys = {name for names in keys.MATERIAL_LAW_KEYS.values() for name in names}
    read = [name for name in keys.MATERIAL_SPEC
            if name not in law_keys or (law == 'linear' and name in keys.MATERIAL_LAW_KEYS[law])]
    m = {name: keys.read(mat, 'material', name, keys.MATERIAL_SPEC) for name in read}
    m['shear_modulus_pa'] = None
    m['silicone'] = 'none'
    if law == 'neo_hookean':
        # the small-strain moduli of an incompressible neo-Hookean solid: E = 3 mu, nu = 1/2,
        # used by the bending, shear, viscous and contact terms (docs/theory/shell_rubber.md)
        m['silicone'] = keys.read(mat, 'material', 'silicone', keys.MATERIAL_SPEC)
        given_mu = (keys.read(mat, 'material', 'shear_modulus_pa', keys.MATERIAL_SPEC)
                    if 'shear_modulus_pa' in mat else 0.0)
        mu = neo_hookean_shear_modulus_pa(mat, m['silicone'], given_mu)
        m['shear_modulus_pa'] = mu
        m['youngs_modulus_pa'] = 3.0 * mu
        m['poisson_ratio'] = keys.NEO_HOOKEAN_POISSON_RATIO
    Ey, eta_v, nu, h = (
        m['youngs_modulus_pa'], m['viscosity_pa_s'], m['poisson_ratio'], m['half_thickness_m']
    )
    kappa = m['shear_correction']
    if h > 0.25 * rmax0:
        raise ModelError(
            f'material.half_thickness_m: {h!r} m is not thin against the mantle radius '
            f'{rmax0:.4g} m; '
            f'allowed: half_thickness_m <= {0.25 * rmax0:.4g} m'
        )
    G = Ey / (2 * (1 + nu))
    part = {
        sk.P_PSI: 2 * Ey * h / (1 - nu**2),
        sk.P_PSI2: 6 * eta_v * h / (1 - nu**2),
        sk.P_JS: h * h / 3,
        sk.P_GS: 2 * h * G * kappa,
        sk.P_GV: 2 * h * eta_v * kappa,
        sk.P_NU: nu,
        sk.P_RLIM: 0.25 * h,
        # axis contact: inner faces meet when the midsurface is one half-thickness from the axis;
        # penalty modulus E over that gap (through-thickness compression of the wall)
        sk.P_HC: h,
        sk.P_KC: Ey / h,
    }
    return m, part


def _read_terms(scene: Mapping[str, Any]) -> dict:
    """Return which physical ``terms`` are on (all by default)."""
    given = keys.section(scene, 'terms', required=False)
    keys.refuse_unknown(given, 'terms', keys.TERMS_SPEC)
    terms = dict(TERMS)
    for k in given:
        terms[k] = keys.read(given, 'terms', k, keys.TERMS_SPEC)
    return terms


def _read_fluid_loads(scene: Mapping[str, Any], rmax0: float) -> tuple[dict, Part]:
    """Return the outer water's ``fluid`` loads: density, added mass, drag; the water inside."""
    fl = keys.section(scene, 'fluid')
    keys.refuse_unknown(fl, 'fluid', keys.FLUID_SPEC)
    out = {}
    for name in keys.FLUID_SPEC:
        derived = 0.5 * rmax0 if name == 'added_mass_length_m' else None
        out[name] = keys.read(fl, 'fluid', name, keys.FLUID_SPEC, default=derived)
    if out['internal_flow_momentum'] and out['internal_inertia'] != 'one_dimensional':
        # the momentum is the reference cavity's 1-D flow's (its S, like its Lambda, is that
        # cavity's): it needs that flow
        raise ModelError(
            f'fluid.internal_flow_momentum: true needs internal_inertia: one_dimensional '
            f'(the scene has {out["internal_inertia"]!r}); allowed: internal_flow_momentum: '
            'false, or internal_inertia: one_dimensional'
        )
    part = {
        sk.P_RHO: out['density_kg_m3'],
        sk.P_CT: out['tangential_drag_coefficient'],
        sk.P_CD: out['drag_coefficient'],
    }
    return out, part


def _read_jet_outlet(
    scene: Mapping[str, Any], coupling: str, terms: dict, ring_radius_m: float
) -> tuple[Mapping, dict, Part]:
    """Return the ``jet``'s outlet, its area and the inlet's, and the thrust coefficient."""
    jet = keys.section(scene, 'jet', required=terms['jet'])
    keys.refuse_unknown(jet, 'jet', keys.JET_SPEC)
    code = coupling == 'paper_code'
    outlet = keys.read(
        jet, 'jet', 'outlet', keys.JET_SPEC,
        default='free_edge_fixed_nozzle' if code else 'edge' if coupling == 'paper' else 'ring',
    )
    rring = ring_radius_m
    if code and outlet != 'free_edge_fixed_nozzle':
        raise ModelError(
            f"jet.outlet: {outlet!r} is not available with coupling: paper_code (the authors' "
            'code: free open end, fixed nozzle Area_out = pi*Rn.^2); '
            'allowed: free_edge_fixed_nozzle'
        )
    if outlet == 'edge':
        if 'outlet_radius_m' in jet:
            raise ModelError(
                f'jet.outlet_radius_m: {jet["outlet_radius_m"]!r} is not used with outlet: '
                f'edge (the outlet is the mantle edge, radius {rring:.4g} m at rest); '
                'allowed: leave it out, or outlet: ring'
            )
        r_out = rring
    else:
        r_out = keys.read(
            jet, 'jet', 'outlet_radius_m', keys.JET_SPEC, high=rring,
            default=min(0.0125, rring) if code else 0.5 * rring,
        )
    A_out = math.pi * r_out**2
    A_in = keys.read(
        jet, 'jet', 'inlet_area_m2', keys.JET_SPEC, default=A_out + 3 * math.pi * 0.01**2
    )
    Cf = keys.read(jet, 'jet', 'thrust_coefficient', keys.JET_SPEC)
    Cc = _contraction_coefficient(jet, outlet, coupling)
    out = {'outlet': outlet, 'free_edge': outlet in ('edge', 'free_edge_fixed_nozzle')}
    # the jet leaves through its vena contracta, Cc A_out (Cc = 1: the outlet itself; 1.0 * A_out
    # is A_out to the bit); the refill opening's default stays the outlet's geometric area
    return jet, out, {sk.P_AOUT: Cc * A_out, sk.P_AIN: A_in, sk.P_CF: Cf}


def _contraction_coefficient(jet: Mapping[str, Any], outlet: str, coupling: str) -> float:
    """
    Return ``jet.contraction_coefficient`` Cc (1: no vena contracta), refusing what it cannot do.

    A sharp-edged exit's jet keeps converging past the outlet to a vena contracta of Cc times
    its area (docs/theory/shell.md, the exit's vena contracta): the jet leaves at ``Q / (Cc A)``
    and the cavity pays for it.  Refused: with ``outlet: edge`` (the moving edge's contraction is
    not modelled); with ``starting_jet`` (both are the exit plane's over-pressure of a converging
    flow, so the two together would count it twice); and outside the consistent coupling (the
    paper couplings have no cavity pressure to pay the faster jet: it would only raise their
    created, unpaid jet energy).
    """
    Cc = keys.read(jet, 'jet', 'contraction_coefficient', keys.JET_SPEC)
    if Cc == 1.0:
        return Cc
    allowed = 'allowed: 1 (or leave it out)'
    if coupling != 'consistent':
        raise ModelError(
            f'jet.contraction_coefficient: {Cc!r} is not available with coupling: {coupling} '
            f'(no cavity pressure pays the faster jet there); {allowed}, or coupling: consistent'
        )
    if outlet == 'edge':
        raise ModelError(
            f'jet.contraction_coefficient: {Cc!r} is not modelled with outlet: edge (the '
            f"mantle's moving edge is the nozzle); {allowed}, or outlet: ring or "
            'free_edge_fixed_nozzle'
        )
    if keys.read(jet, 'jet', 'starting_jet', keys.JET_SPEC):
        raise ModelError(
            f'jet.contraction_coefficient: {Cc!r} is not available with starting_jet: true (both '
            "are the exit plane's over-pressure of a converging flow: together they would count "
            f'it twice); {allowed}, or starting_jet: false'
        )
    return Cc


def _read_water_inside(
    geo: Mapping, fluid: dict, coupling: str, outlet: str, integrator: str, jet_on: bool
) -> Part:
    """Return the inertance (and momentum length) of ``fluid.internal_inertia``'s 1-D flow."""
    internal_inertia = fluid['internal_inertia']
    inertance = 0.0
    momentum_length = 0.0
    if internal_inertia != 'none':
        # the 1-D flow of the water inside (docs/theory/shell.md) ends at the
        # cavity's own open section, so the jet must leave through the free edge; a smaller
        # nozzle would add a contraction whose inertance this reading does not give
        if outlet != 'edge' or coupling == 'paper_code' or integrator == 'verlet' or not jet_on:
            raise ModelError(
                f'fluid.internal_inertia: {internal_inertia!r} is not available with '
                f'coupling: {coupling}, jet.outlet: {outlet}, integrator: {integrator}, '
                f'terms.jet: {str(jet_on).lower()}; allowed: coupling paper or '
                'consistent, jet.outlet: edge, an implicit integrator and the jet on '
                '(or internal_inertia: none)'
            )
        dense = build_reference_meridian(geo, DENSE_ELEMENTS)
        inertance = dense.internal_inertance_per_m()
        if fluid['internal_flow_momentum']:
            momentum_length = dense.internal_momentum_length_m()
    return {
        sk.P_LAMBDA: inertance,
        sk.P_LAMBDA_DEFORMING: float(internal_inertia == 'one_dimensional_deforming'),
        sk.P_SMOM: momentum_length,
    }


def _read_static_load_and_initial_shape(
    scene: Mapping[str, Any], rmax0: float
) -> tuple[float, Part]:
    """Return the ``initial`` radial perturbation, m, and the ``load`` section's pressure."""
    load = keys.section(scene, 'load', required=False)
    keys.refuse_unknown(load, 'load', keys.LOAD_SPEC)
    pstat = keys.read(load, 'load', 'internal_pressure_pa', keys.LOAD_SPEC)
    init = keys.section(scene, 'initial', required=False)
    keys.refuse_unknown(init, 'initial', keys.INITIAL_SPEC)
    pert = keys.read(
        init, 'initial', 'radial_perturbation_m', keys.INITIAL_SPEC,
        low=-0.5 * rmax0, high=0.5 * rmax0,
    )
    return pert, {sk.P_PSTAT: pstat}


def _element_table(meridian: ReferenceMeridian) -> np.ndarray:
    """Return the elements' discrete reference values E (see shell/kernels.py)."""
    X, r0, z0, th0 = meridian.X, meridian.r0, meridian.z0, meridian.theta0
    dr, dz = np.diff(r0), np.diff(z0)
    ds = np.hypot(dr, dz)
    thm = 0.5 * (th0[:-1] + th0[1:])
    r0m = 0.5 * (r0[:-1] + r0[1:])
    lam0 = (dr * np.cos(thm) + dz * np.sin(thm)) / ds
    eta0 = (-dr * np.sin(thm) + dz * np.cos(thm)) / ds
    mu0 = np.diff(th0) / ds
    E = np.zeros((X.size - 1, sk.N_ECOLS))
    E[:, sk.E_DS] = ds
    E[:, sk.E_R0M] = r0m
    E[:, sk.E_LAM0] = lam0
    E[:, sk.E_ETA0] = eta0
    E[:, sk.E_K0] = mu0 * lam0
    E[:, sk.E_VS0] = np.sin(thm) / r0m
    E[:, sk.E_AREA] = 2 * math.pi * r0m * ds
    return E


def _node_masses(
    meridian: ReferenceMeridian, E: np.ndarray, material: dict, fluid: dict, added_mass_on: bool,
    code: bool,
) -> dict:
    """Return the node table Nd with the nodes' masses, added masses and areas filled in."""
    r0, th0 = meridian.r0, meridian.theta0
    n1 = E.shape[0] + 1
    h = material['half_thickness_m']
    area = np.zeros(n1)
    area[:-1] += 0.5 * E[:, sk.E_AREA]
    area[1:] += 0.5 * E[:, sk.E_AREA]
    m = material['density_kg_m3'] * 2 * h * area
    Ca, rho, la = (
        fluid['added_mass_coefficient'], fluid['density_kg_m3'], fluid['added_mass_length_m']
    )
    ma = Ca * rho * la * area if added_mass_on else np.zeros(n1)
    n0 = np.stack([-np.sin(th0), np.cos(th0)], axis=1)
    per_area = Ca * rho * la if added_mass_on else 0.0
    blocks = added_mass_blocks(meridian.r0, meridian.z0, E, per_area)
    Nd = np.zeros((n1, sk.N_NCOLS))
    Nd[:, sk.N_MRR] = m + blocks[:, 0]
    Nd[:, sk.N_MRZ] = blocks[:, 1]
    Nd[:, sk.N_MZZ] = m + blocks[:, 2]
    if code:
        # the authors' code: C_a times the shell's own mass, in every translation
        # (octopus_driver.m: Gammas_ag = Gammas+ro_shel*B*diag([0 0 0 2*h 2*h 2*h]), B = 1.1)
        ma = Ca * m if added_mass_on else np.zeros(n1)
        Nd[:, sk.N_MRR] = m + ma
        Nd[:, sk.N_MRZ] = 0.0
        Nd[:, sk.N_MZZ] = m + ma
        blocks = np.stack([ma, np.zeros(n1), ma], axis=1)
    Nd[:, sk.N_MTT] = material['rotary_inertia_scale'] * m * h * h / 3.0
    Nd[:, sk.N_DAREA] = area
    # axis contact radius: one half-thickness (inner faces meet), but never more than half the
    # node's reference radius (nodes next to the pole sit within a thickness of the axis)
    Nd[:, sk.N_HC] = np.minimum(h, 0.5 * r0)
    return {'Nd': Nd, 'node_mass': m, 'node_added_mass': ma, 'n0': n0, 'am_blocks': blocks}


def added_mass_blocks(r0: np.ndarray, z0: np.ndarray, E: np.ndarray, per_area: float):
    """
    Return the nodes' added-mass blocks (n1, 3): the rr, rz and zz entries, kg.

    Element by element: each element's added mass ``per_area * 2 pi r0m ds`` (``per_area`` =
    C_a rho l_a) acts along the element's reference normal ``n_e`` (its chord's, turned a
    quarter towards the outside); each end node takes half of it, so a node's block is the sum
    over its two element halves of ``m_a,e / 2 * n_e n_e^T``. On a smooth wall this is the nodal
    block ``m_a n0 n0^T`` to O(ds^2); at a kink each side keeps its own normal (the continuous
    water's kinetic energy ``1/2 int C_a rho l_a (n . v)^2 dA`` of a uniform velocity is
    reproduced exactly on a straight-sided meridian).
    """
    dr, dz = np.diff(r0), np.diff(z0)
    chord = np.hypot(dr, dz)
    nr, nz = -dz / chord, dr / chord  # n0 = (-sin theta, cos theta) of the chord's angle
    half = 0.5 * per_area * E[:, sk.E_AREA]
    per_element = np.stack([half * nr * nr, half * nr * nz, half * nz * nz], axis=1)
    blocks = np.zeros((r0.size, 3))
    blocks[:-1] += per_element
    blocks[1:] += per_element
    return blocks


def _node_supports(
    meridian: ReferenceMeridian, E: np.ndarray, nodes: dict, code: bool, free_edge: bool
):
    """
    Hold the pole and the ring (or the edge free, or paper_code's rim clamped) in nodes['Nd'].

    Adds the free nodes, the moving shell's mass and paper_code's rim node to `nodes`.
    """
    Nd, m, th0 = nodes['Nd'], nodes['node_mass'], meridian.theta0
    ne = E.shape[0]
    Nd[0, sk.N_FIXR] = 1.0
    Nd[0, sk.N_FIXT] = 1.0
    Nd[-1, sk.N_FIXR] = Nd[-1, sk.N_FIXZ] = Nd[-1, sk.N_FIXT] = 1.0
    free = np.ones(ne + 1, bool)
    free[0] = free[-1] = False
    if free_edge:
        # our reading of paper 000 section 5.1 ("a shrinkage of the nozzle area"): the edge
        # carries no prescribed radius or angle (zero wrench), only its axial place on the body
        Nd[-1, sk.N_FIXR] = Nd[-1, sk.N_FIXT] = 0.0
        # its axial place is the body's: no r-z coupling of the added mass at that node (the
        # residual would otherwise pull the vehicle speed held in the ring's axial slot into r)
        Nd[-1, sk.N_MRZ] = 0.0
        nodes['am_blocks'][-1, 1] = 0.0
        free[-1] = True
    shell_free_mass = float(m[:-1].sum())
    code_rim = 0
    if code:
        # the authors' code (octopus_driver.m, octopus_derivatives.m): the body holds X = 0, a
        # hole whose wall is at alpha0 = pi/4 (sigmas_o = zeros(6,1)); the open end X = L
        # carries no wrench ("condizioni su X=L"). Here the polar cap up to the first node
        # whose wall is at pi/4 from the pole's is rigid, part of the body, its rim clamped;
        # the edge is free in r, z and theta
        code_rim = int(np.argmax(np.abs(th0 - th0[0]) >= math.pi / 4 - 1e-12))
        if code_rim <= 0 or code_rim >= ne - 1:
            raise ModelError(
                'coupling: paper_code needs a mantle whose wall turns by pi/4 from the pole '
                "before the edge (the clamped rim of the authors' code); "
                'this geometry does not'
            )
        Nd[:code_rim + 1, sk.N_FIXR] = Nd[:code_rim + 1, sk.N_FIXZ] = \
            Nd[:code_rim + 1, sk.N_FIXT] = 1.0
        Nd[-1, sk.N_FIXZ] = 0.0
        free[: code_rim + 1] = False
        shell_free_mass = float(m[code_rim + 1:].sum())
        # the wall-borne load per reference area, on the wall from the rim on only (the
        # rim's share of the cap's element is not wall): its work-equivalent nodal shares
        Nd[:, sk.N_WWALL] = consistent_area_shares(meridian.r0, E[:, sk.E_DS], code_rim)
    nodes.update(free=free, shell_free_mass=shell_free_mass, code_rim=code_rim)


def _read_vehicle(scene: Mapping[str, Any], shell_free_mass: float) -> tuple[dict, Part]:
    """Return the ``vehicle``: its payload, added mass and initial velocity."""
    veh = keys.section(scene, 'vehicle', required=False)
    keys.refuse_unknown(veh, 'vehicle', keys.VEHICLE_SPEC)
    total = keys.read(veh, 'vehicle', 'mass_kg', keys.VEHICLE_SPEC, default=2.0 * shell_free_mass)
    if total <= shell_free_mass:
        raise ModelError(
            f'vehicle.mass_kg: {total!r} kg is not more than the moving shell mass '
            f'{shell_free_mass:.4g} kg; allowed: mass_kg > {shell_free_mass:.4g} '
            '(shell plus payload)'
        )
    mx = keys.read(veh, 'vehicle', 'added_mass_kg', keys.VEHICLE_SPEC)
    out = {
        'payload_kg': total - shell_free_mass,
        'body_added_mass_kg': mx,
        'initial_velocity_m_s': keys.read(veh, 'vehicle', 'initial_velocity_m_s',
                                          keys.VEHICLE_SPEC),
    }
    return out, {sk.P_MBODY: out['payload_kg'] + mx, sk.P_MSHELL: shell_free_mass}


def _read_cable(act: Mapping[str, Any], source: str, X: np.ndarray, free: np.ndarray,
                code_rim: int, Nd: np.ndarray) -> dict:
    """Read the cable's distribution, amplitude and rating; fill the nodes' pull shares."""
    dist = keys.read(act, 'actuation', 'distribution', keys.ACTUATION_SPEC)
    xi = X / X[-1]
    shape = {'uniform': np.ones(X.size), 'rising': xi, 'falling': 1.0 - xi}[dist]
    # the pull is a line load along the deformable meridian (from the pole, or from
    # paper_code's clamped rim) of total ``amplitude``; each node takes its
    # work-equivalent share and the held ends' shares go to the supports, so the
    # discrete load converges to the continuous one at the element's own order
    w = consistent_line_load(X, shape, code_rim) * free
    if w.sum() <= 0:
        raise ModelError(
            f'actuation.distribution: {dist!r} loads no free node; allowed: uniform'
        )
    Nd[:, sk.N_WC] = w
    amp = 0.0
    if source == 'routine' or 'amplitude' in act:  # a command-driven scene keeps its routine's
        amp = keys.read(act, 'actuation', 'amplitude', keys.ACTUATION_SPEC, unit='N')
    # the rating: twice the amplitude when the scene gives one. The wall has no contact model,
    # so a pull that folds the mantle onto itself (about 3x the robot's 8 N) stops the physics;
    # the rating keeps commands below that (test/test_shell_extremes.py holds every shipped cable
    # scene at it)
    rating = keys.read(
        act, 'actuation', 'max_cable_force_n', keys.ACTUATION_SPEC,
        default=2.0 * amp if amp > 0 else keys.CABLE_FORCE_HIGH_N,
    )
    return {'amplitude': amp, 'distribution': dist, 'max_cable_force_n': rating}


def _read_muscle(act: Mapping[str, Any], meridian: ReferenceMeridian, E: np.ndarray) -> dict:
    """Read the muscle's amplitude and desired radius; fill the elements' desired-stretch drop."""
    amp = keys.read(act, 'actuation', 'amplitude', keys.ACTUATION_SPEC, high=0.95)
    taper = keys.read(act, 'actuation', 'taper_fraction', keys.ACTUATION_SPEC)
    desired = keys.read(act, 'actuation', 'desired_radius', keys.ACTUATION_SPEC)
    X = meridian.X
    Xm = 0.5 * (X[:-1] + X[1:]) / X[-1]
    # the meridian's own largest radius (the ring's on the cone), not the midpoints': theirs falls
    # half an element's rise short on a cone, a first-order error in every depth (muscle_depth.md)
    E[:, sk.E_SMUS] = muscle_shape(
        desired, Xm, E[:, sk.E_R0M], taper, amp, float(meridian.r0.max())
    )
    return {'amplitude': amp, 'taper_fraction': taper, 'desired_radius': desired}


def _read_routine(act: Mapping[str, Any]) -> dict:
    """Read the actuation routine's timing: frequency, rise, fall, delay and pulse shape."""
    def value(name, **narrow):
        return keys.read(act, 'actuation', name, keys.ACTUATION_SPEC, **narrow)

    freq = value('frequency_hz')
    per = 1.0 / freq
    tc = value('contraction_s', high=per)
    tr = value('release_s', high=per)
    if tc + tr > per * (1 + 1e-12):
        raise ModelError(
            'actuation.release_s: contraction_s + release_s = '
            f'{tc + tr:.4g} s exceeds the period 1/frequency_hz = {per:.4g} s; '
            'allowed: contraction_s + release_s <= period'
        )
    return {
        'frequency_hz': freq, 'contraction_s': tc, 'release_s': tr,
        'start_delay_s': value('start_delay_s'), 'pulse': value('pulse'),
    }


def _read_actuation(
    scene: Mapping[str, Any], meridian: ReferenceMeridian, E: np.ndarray, nodes: dict
) -> tuple[dict, int, Part]:
    """
    Return the ``actuation`` (cable or muscle actuation), its kernel flags and its parameters.

    Fills the nodes' cable shares or the elements' desired-stretch drop.
    """
    act = keys.section(scene, 'actuation', required=False)
    akind = keys.read(act, 'actuation', 'kind', keys.ACTUATION_SPEC)
    actuation = {'kind': akind, 'source': 'none'}
    flags = 0
    amp = 0.0
    timing = {'frequency_hz': 1.0, 'contraction_s': 0.3, 'release_s': 0.3, 'start_delay_s': 0.0,
              'pulse': 'half_cosine'}
    # kind none is off: it leaves the other kinds' keys unread (a scene overrides the kind
    # alone to switch actuation off), but a key no kind takes is still refused
    keys.refuse_unknown(act, 'actuation', keys.ACTUATION_KIND_KEYS.get(akind, keys.ACTUATION_SPEC))
    if akind != 'none':
        source = keys.read(act, 'actuation', 'source', keys.ACTUATION_SPEC,
                           choices=('routine', 'command') if akind == 'cable' else ('routine',))
        actuation['source'] = source
        if akind == 'cable':
            flags |= sk.F_CABLE
            cable = _read_cable(act, source, meridian.X, nodes['free'], nodes['code_rim'],
                                nodes['Nd'])
            amp = cable.pop('amplitude')
            actuation.update(cable)
        else:
            flags |= sk.F_MUSCLE
            muscle = _read_muscle(act, meridian, E)
            amp = muscle.pop('amplitude')
            actuation.update(muscle)
        if source == 'routine':
            flags |= sk.F_ROUTINE
            timing = _read_routine(act)
            actuation.update(amplitude=amp, **timing)
    part = {
        sk.P_AMP: amp,
        sk.P_FREQ: timing['frequency_hz'],
        sk.P_PULSE: PULSE_SHAPES[timing['pulse']],
        sk.P_TC: timing['contraction_s'],
        sk.P_TR: timing['release_s'],
        sk.P_DELAY: timing['start_delay_s'],
    }
    return actuation, flags, part


def _switch_flags(coupling: str, outlet: str, terms: dict, viscosity_pa_s: float) -> int:
    """Return the kernels' switches (F_*) of the coupling, the outlet and the terms."""
    flags = 0
    if coupling == 'paper':
        flags |= sk.F_PAPER
    if outlet == 'edge':
        flags |= sk.F_EDGE
    if coupling == 'paper_code':
        flags |= sk.F_CODE
    if terms['viscosity'] and viscosity_pa_s > 0:
        flags |= sk.F_VISC
    if terms['drag']:
        flags |= sk.F_DRAG
    if terms['jet']:
        flags |= sk.F_JET
    if terms['vehicle_motion']:
        flags |= sk.F_BODY
    return flags


def muscle_shape(
    desired: str, Xm: np.ndarray, r0m: np.ndarray, taper: float, amp: float, rmax_m: float
) -> np.ndarray:
    """
    Return, per element, the drop of the desired hoop stretch at full activation over ``amp``.

    ``tau_d = 1 - amp a(t) s_e``.

    ``proportional``: the desired radius is ``(1 - amp a s(X)) r0``, a uniform fraction of the rest
    radius.  ``constant_depth`` (our reading of paper 000's Fig. 12, whose curves are lost: "the
    desired radius function is linear (constant) for most of the mantle profile and thus more
    attuned with the linear conical profile"): the desired radius is the rest profile moved inwards
    by the same depth ``amp a(t) rmax_m s(X)`` everywhere, so on a cone it is again a straight
    line parallel to the wall, and on an ellipsoid it is the ellipse moved inwards; the hoop strain
    it asks for is then largest where the mantle is narrow, capped at a desired stretch of 0.05.
    ``s(X)`` is 1 over the mantle and falls smoothly to 0 over ``taper`` of the meridian at the
    pole and at the edge.  ``rmax_m``, m: the reference meridian's largest radius, ``max(r0)``
    over its nodes (the ring's radius on a cone); ``Xm`` the midpoints' arc length over the
    meridian's, ``r0m`` their radii, m.

    ``constant_depth_to_edge`` (a third reading of Fig. 12, run as an experiment):
    ``constant_depth`` held up to the free edge, tapered at the pole only.  Section 5.2 says the
    function is "linear (constant) for most of the mantle profile", and the muscles are "a network
    of circular muscles symmetrically arranged all around the body" (introduction): the part of the
    profile where the function is not linear is read as the pole (the cone's rounded tip, where a
    constant depth cannot hold), not the edge, so the muscle narrows the nozzle too.
    """

    def smooth(x):
        x = np.clip(x, 0.0, 1.0)
        return x * x * (3 - 2 * x)

    if desired == 'constant_depth_to_edge':
        s = smooth(Xm / taper)
    else:
        s = smooth(Xm / taper) * smooth((1 - Xm) / taper)
    if desired == 'proportional':
        return s
    depth = s * rmax_m / r0m
    return np.minimum(depth, 0.95 / amp) if amp > 0 else depth


def consistent_line_load(X: np.ndarray, density: np.ndarray, start: int = 0) -> np.ndarray:
    """
    Return the work-equivalent nodal shares of a line load along the meridian, summing to 1.

    ``density`` gives the load per unit reference arc length at the nodes ``X`` (any scale; it is
    linear between nodes, which holds exactly for the cable's uniform, rising and falling
    distributions); the load acts on ``X >= X[start]`` (the deformable wall).  Node i receives
    ``int f N_i dX / int f dX`` with N_i the linear element's hat function: the consistent nodal
    load vector of the finite element method (Zienkiewicz, Taylor & Zhu, The Finite Element
    Method: Its Basis and Fundamentals, 7th ed., sec. 3.2-3.3, "equivalent nodal forces"; Hughes,
    The Finite Element Method, sec. 1.10 and 3.8, the load vector ``F_i = int N_i f``), integrated
    exactly on each element: ``h (2 f_a + f_b)/6`` to its first node, ``h (f_a + 2 f_b)/6`` to its
    second.  The shares therefore reproduce the continuous load's total and its first moment
    ``int X f dX`` exactly at any mesh (sum_i N_i = 1, sum_i X_i N_i = X).  Shares of nodes that
    are held (the pole's r, a clamped ring) are the supports' part of the load: the caller drops
    them, they do not go to the free nodes (lumping them there was the first-order mesh error of
    issue 23).
    """
    X = np.asarray(X, dtype=float)
    f = np.asarray(density, dtype=float)
    out = np.zeros(X.size)
    h = np.diff(X)[start:]
    fa = f[start:-1]
    fb = f[start + 1:]
    out[start:-1] += h * (2.0 * fa + fb) / 6.0
    out[start + 1:] += h * (fa + 2.0 * fb) / 6.0
    total = float(np.sum(h * (fa + fb) / 2.0))
    if total <= 0.0:
        return out
    return out / total


def consistent_area_shares(r0: np.ndarray, ds: np.ndarray, start: int = 0) -> np.ndarray:
    """
    Return the work-equivalent nodal shares of a load uniform per reference area (sum 1).

    The surface of revolution of the (straight) elements from node ``start`` on: node a of an
    element of chord ``ds`` gets ``int N_a 2 pi r dS = 2 pi ds (2 r_a + r_b)/6``, node b
    ``2 pi ds (r_a + 2 r_b)/6`` (r linear along the chord), the consistent load vector of
    ``consistent_line_load`` with the density 2 pi r (same references).
    """
    r0 = np.asarray(r0, dtype=float)
    out = np.zeros(r0.size)
    d = np.asarray(ds, dtype=float)[start:]
    ra = r0[start:-1]
    rb = r0[start + 1:]
    out[start:-1] += d * (2.0 * ra + rb) / 6.0
    out[start + 1:] += d * (ra + 2.0 * rb) / 6.0
    return out / float(np.sum(d * (ra + rb) / 2.0))


class ShellModel:
    """Axisymmetric Reissner shell mantle + jet + vehicle (implements the Model protocol)."""

    name = 'shell'
    code_rim = 0  # paper_code: the node of the clamped rim around the pole
    isotropic_added_mass = False
    ring_added_mass_kg = 0.0  # the held ring's element half's axial added mass, on the vehicle
    material_law = 'linear'  # material.law (from_scene)
    shear_modulus_pa = None  # neo_hookean: mu, Pa
    silicone = 'none'  # neo_hookean: the tabled silicone, if one was named

    def __init__(
        self,
        *,
        meridian: ReferenceMeridian,
        dt_s: float,
        integrator: str,
        flags: int,
        P: np.ndarray,
        E: np.ndarray,
        Nd: np.ndarray,
        node_mass: np.ndarray,
        node_added_mass: np.ndarray,
        n0: np.ndarray,
        am_blocks: np.ndarray,
        payload_kg: float,
        body_added_mass_kg: float,
        actuation: dict,
        initial_perturbation_m: float = 0.0,
        initial_velocity_m_s: float = 0.0,
        duration_s: float | None = None,
    ):
        self.ref = meridian
        self.dt_s = float(dt_s)
        self.integrator = integrator
        self.scheme, self.alpha = INTEGRATORS[integrator]
        self.flags = int(flags)
        self.P = P
        self.E = E
        self.Nd = Nd
        self.node_mass = node_mass
        self.node_added_mass = node_added_mass
        self.n0 = n0
        #: the nodes' added-mass blocks (rr, rz, zz), kg: the added-mass part of Nd's mass blocks
        self.am_blocks = am_blocks
        self.payload_kg = payload_kg
        self.body_added_mass_kg = body_added_mass_kg
        self.actuation = actuation
        #: the actuators' ranges (Simulation.command_limits): the cable's rating
        self.command_limits = dict(Command.LIMITS)
        if 'max_cable_force_n' in actuation:
            self.command_limits['cable_force_n'] = (0.0, float(actuation['max_cable_force_n']))
        self.initial_perturbation_m = initial_perturbation_m
        self.initial_velocity_m_s = initial_velocity_m_s
        self.duration_s = duration_s
        self.n_nodes = meridian.X.size
        # the published mantle radius: the node at half the meridian's length, which moves with the
        # mantle (the largest radius is often the clamped ring's, constant)
        self.mid_node = int(np.argmin(np.abs(meridian.X - 0.5 * meridian.X[-1])))
        self.substep_events = 0
        self.specialise_kernel = False
        self.keep_newton_workspace = False
        self._workspace = None
        self._initial_energy = None
        self._initial_energy = self._stored(self.initial_state())[0]

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_scene(cls, scene: Mapping[str, Any]) -> 'ShellModel':
        """
        Build from a parsed scene dict (keys: shell/scene_keys.py; e.g. config/shell_robot.yaml).

        Raises ModelError naming the key, the bad value and what is allowed.
        """
        coupling = _read_coupling(scene)
        sim, p_integrator = _read_integrator(scene, coupling)
        geo, meridian, p_shape = _read_geometry_and_mesh(scene)
        rmax0 = float(meridian.r0.max())
        material, p_material = _read_material(scene, rmax0)
        terms = _read_terms(scene)
        fluid, p_fluid = _read_fluid_loads(scene, rmax0)
        jet, outlet, p_jet = _read_jet_outlet(scene, coupling, terms, meridian.ring_radius_m)
        integrator = sim['integrator']
        p_water = _read_water_inside(geo, fluid, coupling, outlet['outlet'], integrator,
                                     terms['jet'])
        formation_number = starting_jet_setting(jet, coupling, integrator, terms['jet'])
        pert, p_load = _read_static_load_and_initial_shape(scene, rmax0)
        E = _element_table(meridian)
        code = coupling == 'paper_code'
        nodes = _node_masses(meridian, E, material, fluid, terms['added_mass'], code)
        _node_supports(meridian, E, nodes, code, outlet['free_edge'])
        vehicle, p_vehicle = _read_vehicle(scene, nodes['shell_free_mass'])
        actuation, actuation_flags, p_actuation = _read_actuation(scene, meridian, E, nodes)
        flags = _switch_flags(coupling, outlet['outlet'], terms, material['viscosity_pa_s'])
        flags |= actuation_flags
        if material['law'] == 'neo_hookean':
            flags |= sk.F_NEO_HOOKEAN

        P = np.zeros(sk.N_PARAMS)
        for part in (p_integrator, p_shape, p_material, p_fluid, p_jet, p_water, p_load,
                     p_vehicle, p_actuation):
            for index, value in part.items():
                P[index] = value
        P[sk.P_FORMATION_NUMBER] = formation_number
        # the held ring's (or free edge's) element half: its water moves axially with the
        # vehicle, so its axial added mass is the vehicle's (its drag reaches the vehicle through
        # the ring's reaction, kernels.forces); the paper couplings keep their own vehicles
        ring_am = float(nodes['am_blocks'][-1, 2]) if coupling == 'consistent' else 0.0
        P[sk.P_MBODY] += ring_am
        # Newton's velocity scale: the shortest element per step
        P[sk.P_VSCALE] = float(E[:, sk.E_DS].min()) / sim['dt_s']

        model = cls(
            meridian=meridian,
            dt_s=sim['dt_s'],
            integrator=integrator,
            flags=flags,
            P=P,
            E=E,
            Nd=nodes['Nd'],
            node_mass=nodes['node_mass'],
            node_added_mass=nodes['node_added_mass'],
            n0=nodes['n0'],
            am_blocks=nodes['am_blocks'],
            payload_kg=vehicle['payload_kg'],
            body_added_mass_kg=vehicle['body_added_mass_kg'],
            actuation=actuation,
            initial_perturbation_m=pert,
            initial_velocity_m_s=vehicle['initial_velocity_m_s'],
            duration_s=sim['duration_s'],
        )
        model.specialise_kernel = sim['specialise_kernel']
        model.keep_newton_workspace = sim['keep_newton_workspace']
        model.coupling = coupling
        model.outlet = outlet['outlet']
        model.isotropic_added_mass = code
        model.ring_added_mass_kg = ring_am
        model.code_rim = nodes['code_rim']
        if code or ring_am:
            model._initial_energy = model._stored(model.initial_state())[0]
        model.material = {
            name: material[name]
            for name in ('youngs_modulus_pa', 'viscosity_pa_s', 'poisson_ratio',
                         'half_thickness_m', 'density_kg_m3')
        }
        #: the wall's elastic law and, with neo_hookean, its shear modulus mu (Pa) and silicone
        model.material_law = material['law']
        model.shear_modulus_pa = material['shear_modulus_pa']
        model.silicone = material['silicone']
        model._refuse_steps_it_cannot_run()
        return model

    def _refuse_steps_it_cannot_run(self) -> None:
        """Refuse a step above verlet's stable step, or one that does not resolve the routine."""
        dt = self.dt_s
        if self.integrator == 'verlet':
            bound = self.stable_step_s(self.initial_state())
            if dt > bound:
                m = self.material
                raise ModelError(
                    f'simulation.dt_s: {dt!r} s exceeds the explicit (verlet) stable step '
                    f'{bound:.3g} s of this shell (E={m["youngs_modulus_pa"]:g} Pa, '
                    f'eta_v={m["viscosity_pa_s"]:g} Pa s, '
                    f'{self.E.shape[0]} elements); allowed: dt_s <= {bound:.3g} s, '
                    'or integrator: implicit_midpoint / backward_euler'
                )
        if self.flags & sk.F_ROUTINE:
            tc, tr, freq = self.P[sk.P_TC], self.P[sk.P_TR], self.P[sk.P_FREQ]
            limit = min(tc, tr, 1.0 / freq) / 10.0
            if dt > limit:
                raise ModelError(
                    f'simulation.dt_s: {dt!r} s does not resolve the actuation routine '
                    f'(contraction {tc:g} s, release {tr:g} s); allowed: dt_s <= {limit:.3g} s '
                    '(a tenth of the shortest phase)'
                )

    # ------------------------------------------------------------------ protocol
    @property
    def n_state(self) -> int:
        return 6 * self.n_nodes + sk.N_TAIL

    def initial_state(self) -> np.ndarray:
        n1 = self.n_nodes
        s = np.zeros(self.n_state)
        q = s[: 3 * n1].reshape(n1, 3)
        q[:, 0] = self.ref.r0
        q[:, 1] = self.ref.z0
        q[:, 2] = self.ref.theta0
        if self.initial_perturbation_m:
            xi = self.ref.X / self.ref.X[-1]
            q[1:-1, 0] += self.initial_perturbation_m * np.sin(math.pi * xi[1:-1])
        tail = 6 * n1
        U0 = self.initial_velocity_m_s if self.flags & sk.F_BODY else 0.0
        s[tail + sk.S_U] = U0
        v = s[3 * n1:6 * n1].reshape(n1, 3)
        if self.flags & sk.F_CODE:
            # the polar cap is the body's; the wall moves with the vehicle
            v[self.code_rim + 1:, 1] = U0
        elif not self.flags & sk.F_PAPER:
            v[1:-1, 1] = U0  # wall moving with the vehicle (absolute axial velocity)
            v[0, 1] = U0
        s[tail + sk.S_VOL] = self.ref.volume_m3()
        return s

    def _cmd_amp(self, command: Command | None) -> float:
        if command is None or self.actuation.get('source') != 'command':
            return 0.0
        return float(command.cable_force_n)

    def advance(self, state: np.ndarray, time_s: float, n_steps: int, command: Command) -> int:
        """
        Advance in place by ``n_steps`` steps of ``dt_s``.

        Implicit schemes: a step whose Newton solve fails (violent collapse, wall contact) is
        retried as 4, 16, then 64 sub-steps (counted in ``self.substep_events``); only if that
        fails too, or on a non-finite / out-of-bounds state, SimulationBlowUp is raised with the
        state at the last good step.
        """
        if n_steps <= 0:
            return 0
        kern = self._kernel()
        ws = (
            self._newton_workspace(state)
            if self.keep_newton_workspace and self.scheme == 1
            else None
        )
        amp = self._cmd_amp(command)
        t = float(time_s)
        remaining = int(n_steps)
        total = 0
        while remaining > 0:
            if ws is not None:
                done, code = sk.advance_kept(
                    self.flags, state, t, remaining, amp, self.E, self.Nd, self.P, self.scheme,
                    ws[0], ws[1],
                )
            else:
                done, code = kern(
                    self.flags, state, t, remaining, amp, self.E, self.Nd, self.P, self.scheme
                )
            total += done
            remaining -= done
            t = float(time_s) + total * self.dt_s
            if code == sk.OK:
                break
            if code == sk.ERR_NEWTON and self.scheme == 1:
                ok = False
                for m in (4, 16, 64):
                    trial = state.copy()
                    P2 = self.P.copy()
                    P2[sk.P_DT] = self.dt_s / m
                    d2, c2 = kern(self.flags, trial, t, m, amp, self.E, self.Nd, P2, self.scheme)
                    if c2 == sk.OK:
                        state[:] = trial
                        ok = True
                        self.substep_events += 1
                        break
                if ok:
                    total += 1
                    remaining -= 1
                    t = float(time_s) + total * self.dt_s
                    continue
            raise SimulationBlowUp(
                f'shell model stopped at t={t:.6g} s: {ERR_TEXT.get(code, code)} '
                f'(state kept at the last good step, dt_s={self.dt_s:g}, '
                f'integrator={self.integrator}){self._diagnose(state)}',
                t,
            )
        return total

    def _newton_workspace(self, state: np.ndarray) -> tuple:
        """
        Return the Newton workspace kept across ``advance`` calls: (J, W) of ``sk.advance_kept``.

        (``simulation.keep_newton_workspace: true``.)  The factorised Newton matrix and the
        predictor's history continue from the previous call only if this call continues it: the
        state is the one that call left (bit for bit; a reset, a state set from outside or
        another simulation of the same model is not) and the parameters, the step among them,
        are unchanged; a failed step or a sub-stepped one (the state then differs) starts afresh.
        ``advance_kept`` checks that; allocated once per model.
        """
        ws = self._workspace
        if ws is None or ws[1].size != sk.workspace_length(self.n_nodes, state.size):
            ws = self._workspace = (
                np.zeros((3 * self.n_nodes, 2 * sk.BW + 1)),
                np.zeros(sk.workspace_length(self.n_nodes, state.size)),
            )
            ws[1][sk.WS_LEN:] = np.nan  # no state or parameters left by a previous call
        return ws

    def reset_workspace(self) -> None:
        """Forget the kept Newton workspace (Simulation.reset calls this)."""
        if self._workspace is not None:
            self._workspace[1][:sk.WS_LEN] = 0.0

    def _diagnose(self, state) -> str:
        """
        Explain why a run may have failed, from the last good state.

        Names the most compressed meridian element and hoop.  The Kelvin-Voigt law on Green strains
        (Saint-Venant-Kirchhoff) softens in compression below a stretch of 1/sqrt(3) = 0.577, where
        an element can fold through itself; without viscosity nothing damps the resulting
        mesh-scale crumpling.
        """
        n1 = self.n_nodes
        q = state[: 3 * n1].reshape(n1, 3)
        if not np.all(np.isfinite(q)):
            return ''
        ds = self.E[:, sk.E_DS]
        lam = np.hypot(np.diff(q[:, 0]), np.diff(q[:, 1])) / ds
        tau = 0.5 * (q[:-1, 0] + q[1:, 0]) / self.E[:, sk.E_R0M]
        e = int(np.argmin(lam))
        xm = 0.5 * (self.ref.X[e] + self.ref.X[e + 1]) / self.ref.X[-1]
        msg = (
            f'; last good state: most compressed meridian element stretch {lam[e]:.3g} '
            f'at X/L={xm:.2f}, '
            f'smallest hoop stretch {tau.min():.3g}'
        )
        if lam[e] < 1 / math.sqrt(3):
            msg += (
                ' (below 0.577 the Saint-Venant-Kirchhoff membrane law softens and the wall can '
                'fold through itself)'
            )
        if tau.min() < 1 / math.sqrt(3):
            msg += (
                ' (hoop stretch below 0.577: the hoop force of that law softens, the wall snaps '
                'towards the axis)'
            )
        if not self.flags & sk.F_VISC:
            msg += '; the wall has no viscosity (nothing damps mesh-scale crumpling)'
        remedy = 'a smaller actuation amplitude, a smaller dt_s'
        if not self.flags & sk.F_VISC:
            remedy += ', or material viscosity > 0'
        return msg + f'; what would work: {remedy}'

    def _kernel(self):
        """
        Return the compiled advance kernel: generic (runtime flags, default) or flag-specialised.

        ``sk.advance_specialised`` forces ``flags`` to a literal (dead terms are compiled out), but
        every call through the dispatcher then pays ~8 ms of literal re-dispatch; so it is called
        once (0 steps) to compile or load the specialisation from the cache, and its entry point is
        kept.
        """
        if not self.specialise_kernel:
            return sk.advance
        fn = _KERNELS.get(self.flags)
        if fn is None:
            dummy = self.initial_state()
            sk.advance_specialised(
                self.flags, dummy, 0.0, 0, 0.0, self.E, self.Nd, self.P, self.scheme
            )
            for sig, cres in sk.advance_specialised.overloads.items():
                lit = getattr(sig[0], 'literal_value', None)
                if lit == self.flags:
                    fn = cres.entry_point
                    break
            if (
                fn is None
            ):  # pragma: no cover - numba internals changed: fall back to the generic kernel
                fn = sk.advance
            _KERNELS[self.flags] = fn
        return fn

    def routine_command(self, time_s: float) -> Command:
        """
        Return the command the built-in routine applies at ``time_s``.

        Cable force; muscle: none.
        """
        if self.actuation.get('kind') == 'cable' and self.flags & sk.F_ROUTINE:
            a, _ = sk.routine(float(time_s), self.P)
            return Command(cable_force_n=float(self.P[sk.P_AMP] * a))
        return Command()

    def activation(self, time_s: float) -> float:
        """Routine activation a(t) in [0, 1] (0 without a routine)."""
        if not self.flags & sk.F_ROUTINE:
            return 0.0
        return float(sk.routine(float(time_s), self.P)[0])

    def _eval(self, state, command=None):
        t = float(state[6 * self.n_nodes + sk.S_TIME])
        return sk.evaluate(self.flags, state, t, self._cmd_amp(command), self.E, self.Nd, self.P)

    def observe(self, state: np.ndarray, time_s: float, command: Command) -> Observation:
        n1 = self.n_nodes
        tail = 6 * n1
        T = state[tail:]
        # the volume alone, not a whole force evaluation (the same bits as forces' volume)
        vol = float(sk.cavity_volume(state, n1))
        rho = self.P[sk.P_RHO]
        return Observation(
            time_s=float(time_s),
            position_m=float(T[sk.S_X]),
            velocity_m_s=float(T[sk.S_U]),
            acceleration_m_s2=float(T[sk.S_A]),
            mantle_radius_m=float(state[3 * self.mid_node]),
            volume_m3=vol,
            fluid_mass_kg=float(rho * vol),
            thrust_n=float(T[sk.S_THR]),
            added_mass_force_n=0.0,
            drag_n=float(T[sk.S_BDRAG]),
            jet_speed_m_s=float(T[sk.S_UJ]),
            cavity_pressure_pa=float(T[sk.S_P]),
            pump_flow_m3_s=0.0,
            valve_opening=1.0,
        )

    def _stored(self, state):
        n1 = self.n_nodes
        v = state[3 * n1:6 * n1].reshape(n1, 3).copy()
        v[:, 0] *= 1.0 - self.Nd[:, sk.N_FIXR]
        v[:, 1] *= 1.0 - self.Nd[:, sk.N_FIXZ]
        v[:, 2] *= 1.0 - self.Nd[:, sk.N_FIXT]
        k_own = 0.5 * float(
            np.sum(
                self.node_mass * (v[:, 0] ** 2 + v[:, 1] ** 2)
                + self.Nd[:, sk.N_MTT] * v[:, 2] ** 2
            )
        )
        b = self.am_blocks
        k_am = 0.5 * float(np.sum(
            b[:, 0] * v[:, 0] ** 2 + 2.0 * b[:, 1] * v[:, 0] * v[:, 1] + b[:, 2] * v[:, 1] ** 2
        ))
        return self._stored_with(state, k_own, k_am)

    def _stored_many(self, states: np.ndarray) -> list[tuple]:
        """
        Return _stored of each row of states (m, state size), the same bits.

        The node sums for all rows at once: the same element-wise products, each row summed by
        numpy's reduction along the row as np.sum sums a 1-D array (test_shell checks the bits).
        """
        n1 = self.n_nodes
        free = 1.0 - self.Nd[:, [sk.N_FIXR, sk.N_FIXZ, sk.N_FIXT]]
        v = states[:, 3 * n1:6 * n1].reshape(len(states), n1, 3) * free
        vr, vz = v[:, :, 0], v[:, :, 1]
        own = np.add.reduce(
            self.node_mass * (vr**2 + vz**2) + self.Nd[:, sk.N_MTT] * v[:, :, 2] ** 2, axis=1
        )
        b = self.am_blocks
        am = np.add.reduce(b[:, 0] * vr**2 + 2.0 * b[:, 1] * vr * vz + b[:, 2] * vz**2, axis=1)
        return [
            self._stored_with(state, 0.5 * float(k_own), 0.5 * float(k_am))
            for state, k_own, k_am in zip(states, own.tolist(), am.tolist())
        ]

    def _stored_with(self, state, k_own: float, k_am: float):
        """Return the stored energies of state, J, given the kinetic energies k_own and k_am."""
        n1 = self.n_nodes
        st, _, _, kint = self._eval(state)
        U = float(state[6 * n1 + sk.S_U])
        k_veh = 0.5 * self.payload_kg * U * U + k_own
        if self.flags & sk.F_PAPER:
            # node velocities are relative to the body: the vehicle carries the shell's own mass
            k_veh += 0.5 * float(self.P[sk.P_MSHELL]) * U * U
        k_out = 0.5 * (self.body_added_mass_kg + self.ring_added_mass_kg) * U * U + k_am
        el = float(st[sk.T_EEL])
        # the water inside flowing towards the open end (0 unless fluid.internal_inertia is on)
        k_flow = 0.5 * float(self.P[sk.P_RHO] * self.inertance(state)) * float(st[sk.T_VDOT]) ** 2
        k_cross = 0.0
        if not self.flags & sk.F_PAPER:
            # the earth-frame cross term rho S U V' of that flow (its momentum; 0 without it);
            # the paper coupling's shell has no frame, its vehicle force is booked as created
            k_cross = float(self.P[sk.P_RHO] * self.P[sk.P_SMOM]) * U * float(st[sk.T_VDOT])
        total = el + k_veh + k_out + float(kint) + k_flow + k_cross
        return total, el, k_veh, k_out, float(kint), k_flow, k_cross

    def inertance(self, state: np.ndarray) -> float:
        """Inertance of the water inside at ``state``, 1/m (0 without fluid.internal_inertia)."""
        if self.P[sk.P_LAMBDA_DEFORMING] > 0.5:
            n = 3 * self.n_nodes
            return float(sk.inertance(state[:n].copy(), self.n_nodes, np.zeros(n)))
        return float(self.P[sk.P_LAMBDA])

    def energy_ledger(self, state: np.ndarray) -> dict[str, float]:
        return self._ledger(state, self._stored(state))

    def energy_ledgers(self, states: np.ndarray) -> list[dict[str, float]]:
        """Return energy_ledger of each row of states (m, state size): the same values, faster."""
        return [
            self._ledger(state, stored)
            for state, stored in zip(states, self._stored_many(np.asarray(states)))
        ]

    def _ledger(self, state: np.ndarray, stored: tuple) -> dict[str, float]:
        tot, el, kv, ko, ki, kf, kc = stored
        T = state[6 * self.n_nodes:]
        led = {
            'stored_elastic': el,
            'stored_kinetic_vehicle': kv,
            'stored_kinetic_outer_fluid': ko,
            'stored_kinetic_internal': ki,
            'in_actuation_work': float(T[sk.S_IN]),
            'in_initial': float(self._initial_energy),
            'out_jet_kinetic': float(T[sk.S_JET]),
            'out_drag': float(T[sk.S_DRAG]),
            'out_viscous': float(T[sk.S_VISC]),
            'out_other': float(T[sk.S_OTHER]),
        }
        if self.P[sk.P_LAMBDA] > 0.0:
            led['stored_kinetic_internal_flow'] = kf
        if self.P[sk.P_SMOM] > 0.0 and not self.flags & sk.F_PAPER:
            led['stored_kinetic_internal_cross'] = kc
        if self.P[sk.P_FORMATION_NUMBER] > 0.0:
            # jet.starting_jet: the exit over-pressure's share of out_jet_kinetic (not an own flow)
            led['jet_overpressure_work'] = float(T[sk.S_OVERPRESSURE_WORK])
        out = led['out_jet_kinetic'] + led['out_drag'] + led['out_viscous'] + led['out_other']
        created = 0.0
        if self.flags & sk.F_PAPER:
            # not an input: the energy the paper's equations create, named (docs/theory/shell.md)
            created = led['created_unpaid_jet_kinetic'] = float(T[sk.S_CREATED])
            if self.P[sk.P_SMOM] > 0.0:
                led['created_unpaid_internal_momentum'] = float(T[sk.S_CREATED_MOM])
                created += led['created_unpaid_internal_momentum']
        elif self.flags & sk.F_CODE:
            # the authors' code (docs/validation/papers.md): the unpaid jet, and the work of the
            # wall-borne thrust, refill force and drag beyond what the books charge at the
            # vehicle's speed
            led['created_unpaid_jet_kinetic'] = float(T[sk.S_CREATED])
            led['created_wall_loads'] = float(T[sk.S_CREATED_WALL])
            created = led['created_unpaid_jet_kinetic'] + led['created_wall_loads']
        err = tot - led['in_initial'] - led['in_actuation_work'] + out - created
        led['closure_error'] = float(err)
        led['closure_relative'] = float(
            err / max(led['in_initial'] + led['in_actuation_work'], 1e-300)
        )
        return led

    def profile_of(self, state):
        n1 = self.n_nodes
        q = state[: 3 * n1].reshape(n1, 3)
        return q[:, 0].copy(), q[:, 1].copy()

    def profile(self, state: np.ndarray):
        """(r_m, z_m) node arrays of the current meridian (body frame, ring at z = 0)."""
        return self.profile_of(state)

    def profile_sample(self, state: np.ndarray) -> np.ndarray:
        """Return the part of ``state`` profile() reads (a view): node coordinates, 3 a node."""
        return state[: 3 * self.n_nodes]

    def profiles_of_samples(self, samples: np.ndarray):
        """Return profile() of many states from profile_sample rows: (r_m, z_m), (n, nodes)."""
        return samples[:, 0::3], samples[:, 1::3]

    def _linearised(self, state: np.ndarray):
        """
        Return the free dofs and their mass M, stiffness K = -dF/dq and damping C = -dF/dv.

        Dense; the body held still (no vehicle dof); M carries the nodes' own and added mass, not
        the water inside (``linear_modes`` adds it).
        """
        n1 = self.n_nodes
        t = float(state[6 * n1 + sk.S_TIME])
        Kb, Cb = sk.stiffness_damping(self.flags, state, t, self.E, self.Nd, self.P)
        n = 3 * n1
        free = np.array([not sk.fixed_dof(self.Nd, k) for k in range(n)])
        K = np.zeros((n, n))
        C = np.zeros((n, n))
        bw = sk.BW
        for i in range(n):
            for j in range(max(0, i - bw), min(n, i + bw + 1)):
                K[i, j] = Kb[i, j - i + bw]
                C[i, j] = Cb[i, j - i + bw]
        M = np.zeros((n, n))
        for i in range(n1):
            M[3 * i, 3 * i] = self.Nd[i, sk.N_MRR]
            M[3 * i, 3 * i + 1] = M[3 * i + 1, 3 * i] = self.Nd[i, sk.N_MRZ]
            M[3 * i + 1, 3 * i + 1] = self.Nd[i, sk.N_MZZ]
            M[3 * i + 2, 3 * i + 2] = self.Nd[i, sk.N_MTT]
        idx = np.flatnonzero(free)
        sub = np.ix_(idx, idx)
        return idx, M[sub], -K[sub], -C[sub]

    def linear_modes(self, state: np.ndarray) -> list[tuple[float, float]]:
        """
        Return the under-damped modes of the mantle about ``state``: (frequency_hz, damping_ratio).

        Undamped natural frequency ``|lambda| / 2 pi`` and damping ratio ``-Re lambda / |lambda|``
        of each complex pair of ``M x'' + C x' + K x = 0``, lowest first; the body held still.
        With ``fluid.internal_inertia`` the water inside adds ``rho Lambda g g^T`` to M
        (g = grad V): its kinetic energy ``1/2 rho Lambda V'^2``.  That water's momentum
        (internal_flow_momentum) couples the wall to the body's speed only, so with the body held
        it adds nothing.
        """
        free, Mf, Kf, Cf = self._linearised(state)
        if self.P[sk.P_LAMBDA] > 0.0:
            g = np.zeros(3 * self.n_nodes)
            sk.volume_grad(state[: 3 * self.n_nodes].copy(), self.n_nodes, g)
            gf = g[free]
            Mf = Mf + self.P[sk.P_RHO] * self.inertance(state) * np.outer(gf, gf)
        n = Mf.shape[0]
        Minv = np.linalg.inv(Mf)
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ Kf, -Minv @ Cf]])
        lam = np.linalg.eigvals(A)
        # under-damped: a clearly complex pair (near-critical clusters come out of the solver
        # with round-off imaginary parts, sqrt(1 - zeta^2) ~ 1e-4)
        pairs = lam[lam.imag > 1e-2 * np.abs(lam)]
        modes = [(abs(x) / (2 * math.pi), -x.real / abs(x)) for x in pairs]
        return sorted(modes)

    def stable_step_s(self, state: np.ndarray) -> float:
        """
        Return the largest stable step of the explicit (verlet) scheme at this state.

        From the generalised eigenvalues of the linearised system at the state: the highest
        circular frequency omega (stiffness K against the mass M, elastic + geometric) and the
        highest damping rate c (Kelvin-Voigt and drag, C against M); central differences with
        damping are stable for dt <= 2/omega (sqrt(1 + xi^2) - xi), xi = c/(2 omega).  A 0.9
        safety factor covers the stiffening of large deformations.
        """
        import scipy.linalg as sla

        _, Mf, Kf, Cf = self._linearised(state)
        Kf = 0.5 * (Kf + Kf.T)
        Cf = 0.5 * (Cf + Cf.T)
        w2 = float(np.max(sla.eigh(Kf, Mf, eigvals_only=True)))
        c = float(np.max(sla.eigh(Cf, Mf, eigvals_only=True))) if np.any(Cf) else 0.0
        w = math.sqrt(max(w2, 1e-30))
        xi = max(c, 0.0) / (2 * w)
        return 0.9 * 2.0 / w * (math.sqrt(1 + xi * xi) - xi)
