"""
The shell model's scene keys (``model: shell``), declared once: rule, unit, default, meaning.

Every key of every section is a `Key`: its rule is the one number, choice or boolean rule of
``pulsejet_sim.core.schema`` (Number, Choice, Flag), with a line saying what it means. Where a
default or a bound depends on other keys (the outlet's radius is at most the ring's, the vehicle
is twice the shell by default, ...), the rule holds the fixed part and `default` / `allowed` say
the rest in words; the scene reader (``ShellModel.from_scene``) narrows the rule to the scene's
values through `read`, so a refusal prints the bound that applies. `python -m
pulsejet_sim.reference` writes the tables of docs/user/reference.md from these declarations.

Reading: `section` returns a section's mapping, `refuse_unknown` refuses a key the section does
not declare, `read` returns one key's value by its rule. Numbers are read as the geometry's are:
what float() reads (``'2.5'`` too), a bool never; a whole number (``Number.integer``) must be an
integer. Every refusal names the key, the value and what is allowed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from typing import Any, Mapping

from pulsejet_sim.core.model_io import Command, ModelError
from pulsejet_sim.core.schema import Choice, Flag, Number, show
from pulsejet_sim.models.rubber import SILICONE_CHOICES
from pulsejet_sim.models.starting_jet import FORMATION_NUMBER, FORMATION_NUMBER_RANGE

# ---- the choices ------------------------------------------------------------------------------
#: the couplings of the wall, the water and the vehicle (docs/theory/shell.md)
COUPLINGS = ('consistent', 'paper', 'paper_code')
#: the time integrators, in the order the refusals list them
INTEGRATOR_NAMES = ('verlet', 'implicit_midpoint', 'backward_euler')
GEOMETRY_KINDS = ('ellipsoid', 'cone', 'cap_cylinder', 'points')
OUTLETS = ('ring', 'edge', 'free_edge_fixed_nozzle')
ACTUATION_KINDS = ('none', 'cable', 'muscle')
DISTRIBUTIONS = ('uniform', 'rising', 'falling')
DESIRED_RADIUS = ('proportional', 'constant_depth', 'constant_depth_to_edge')
#: the water inside: no inertia of its own (paper 000's loads), or paper 001's one-dimensional
#: internal flow carried over to the shell
INTERNAL_INERTIA = ('none', 'one_dimensional', 'one_dimensional_deforming')
#: the routine's rise and fall: half cosines, or straight lines (the authors' code's
#: `triangularPulse`, paper 000's study)
PULSE_NAMES = ('half_cosine', 'triangle')
CABLE_FORCE_HIGH_N = Command.LIMITS['cable_force_n'][1]


@dataclass(frozen=True)
class Key:
    """
    One scene key: its rule (core.schema), what it means and the words for derived values.

    `default` words a default the reader computes from other keys (the rule's own default is then
    None and the key is not required); `allowed` words a bound that depends on other keys (the
    rule holds the bounds that do not).
    """

    rule: Number | Choice | Flag
    doc: str
    default: str = ''
    allowed: str = ''

    @property
    def required(self) -> bool:
        return self.rule.default is None and not self.default


def _number(value, low, high, unit, doc, *, low_open=False, integer=False, **words) -> Key:
    """Return the Key of a number: its rule's default `value` (None: required or derived)."""
    return Key(Number(value, low, high, low_open=low_open, unit=unit, integer=integer),
               doc, **words)


TOP_SPEC = {
    'coupling': Key(
        Choice('consistent', COUPLINGS),
        'consistent: the water, wall and vehicle exchange energy without creating any; paper: '
        "paper 000's equations as written; paper_code: the authors' public code as written (for "
        'auditing it)',
    ),
}
SIMULATION_SPEC = {
    'dt_s': _number(None, 0.0, 0.1, 's', 'the time step (verlet: at most its stable step; a '
                    "routine's shortest phase: at least ten steps)", low_open=True),
    'duration_s': _number(10.0, 0.0, 1e6, 's', "the run's length"),
    'publish_rate_hz': _number(100.0, 1.0, 10000.0, 'Hz',
                               'observations per second of the nodes and the runner'),
    'integrator': Key(
        Choice('implicit_midpoint', INTEGRATOR_NAMES),
        'implicit_midpoint: 2nd order; backward_euler: 1st order, L-stable; verlet: explicit '
        '(refused above its stable step, with the bound in the message; consistent coupling only)',
    ),
    'newton_tolerance': _number(1e-9, 1e-14, 1e-4, '',
                                "the implicit step's Newton tolerance, relative to the shortest "
                                'element per step'),
    'specialise_kernel': Key(Flag(False), "true: a kernel compiled for this scene's switches"),
    'keep_newton_workspace': Key(
        Flag(False),
        "true: the factorised Newton matrix and the predictor's history carry over from one "
        'advance call to the next that continues it (the same bits as one long call; not with '
        'specialise_kernel)',
    ),
}
MESH_SPEC = {
    'elements': _number(None, 4, 400, '', 'elements along the meridian, equal in arc length',
                        integer=True),
}
GEOMETRY_KIND_SPEC = {
    'kind': Key(Choice(None, GEOMETRY_KINDS), "the mantle's reference meridian, from the pole to "
                "the ring (each kind's keys below)"),
}
#: the geometry's keys for each `kind` (read by shell/geometry.py)
GEOMETRY_SPECS = {
    'ellipsoid': {
        'semi_axis_axial_m': _number(None, 1e-3, 10.0, 'm', 'a, along the axis'),
        'semi_axis_radial_m': _number(None, 1e-3, 10.0, 'm', 'b, the largest radius'),
        'opening_radius_m': _number(None, 1e-4, 10.0, 'm',
                                    "the ring's radius, on the rear half, below b",
                                    allowed='[0.0001, semi_axis_radial_m)'),
    },
    'cone': {
        'length_m': _number(None, 1e-3, 10.0, 'm', 'from the apex (front pole) to the ring'),
        'base_radius_m': _number(None, 1e-3, 10.0, 'm', "the ring's radius"),
        'tip_radius_m': _number(None, 0.0, 10.0, 'm',
                                'the sphere rounding the apex (0: sharp)',
                                default='0.2 base_radius_m'),
    },
    'cap_cylinder': {
        'cap_radius_m': _number(None, 1e-3, 10.0, 'm', "the front spherical cap's radius"),
        'cap_opening_rad': _number(None, 0.05, math.pi / 2, 'rad',
                                   'the polar angle the cap is opened to'),
        'cylinder_length_m': _number(None, 0.0, 10.0, 'm', 'from the cap to the ring'),
    },
}
#: the `points` geometry's one key (a list, read by shell/geometry.py)
GEOMETRY_POINTS_DOC = '[[r, z], ...] from the pole (r = 0) to the ring, at least 3 points'
#: the wall's elastic laws (docs/theory/shell_rubber.md): the Kelvin-Voigt law on the Reissner
#: strains, or an incompressible neo-Hookean membrane with the linear bending and shear terms
MATERIAL_LAWS = ('linear', 'neo_hookean')
#: the material keys each law takes (the other law's are refused, models/rubber.py)
MATERIAL_LAW_KEYS = {
    'linear': ('youngs_modulus_pa', 'poisson_ratio'),
    'neo_hookean': ('silicone', 'shear_modulus_pa'),
}
#: neo_hookean: the small-strain moduli of its bending, shear and viscous terms (incompressible)
NEO_HOOKEAN_POISSON_RATIO = 0.5
MATERIAL_SPEC = {
    'law': Key(
        Choice('linear', MATERIAL_LAWS),
        'linear: the Kelvin-Voigt law on the Reissner strains (E, nu); neo_hookean: an '
        'incompressible neo-Hookean membrane (mu), bending and shear linear with E = 3 mu, '
        'nu = 0.5',
    ),
    'youngs_modulus_pa': _number(None, 10.0, 1e10, 'Pa', 'E (linear)',
                                 default='linear: required; neo_hookean: 3 mu, refused if given'),
    'silicone': Key(Choice('none', SILICONE_CHOICES),
                    'neo_hookean: a tabled silicone (models/rubber.py), or give shear_modulus_pa'),
    'shear_modulus_pa': _number(None, 1.0, 3e9, 'Pa', 'mu (neo_hookean), or give silicone',
                                default="the silicone's (neo_hookean)"),
    'viscosity_pa_s': _number(None, 0.0, 1e7, 'Pa s', 'the Kelvin-Voigt viscosity eta_v'),
    'poisson_ratio': _number(None, 0.0, 0.49, '', 'nu (linear)',
                             default='linear: required; neo_hookean: 0.5, refused if given'),
    'half_thickness_m': _number(None, 1e-6, 0.1, 'm', 'h; at most a quarter of the largest radius',
                                allowed='[1e-06, 0.1], <= 0.25 max(r0)'),
    'density_kg_m3': _number(None, 10.0, 30000.0, 'kg/m^3', "the wall's density"),
    'shear_correction': _number(1.0, 0.1, 1.0, '', 'kappa, of the transverse shear stiffness'),
    'rotary_inertia_scale': _number(1.0, 1.0, 1e6, '', "times the wall's rotary inertia m h^2/3"),
}
TERMS_SPEC = {
    'viscosity': Key(Flag(True), "the wall's Kelvin-Voigt viscosity"),
    'drag': Key(Flag(True), 'the tangential drag on the wall and the body drag'),
    'added_mass': Key(Flag(True), "the outer water's added mass on the wall"),
    'jet': Key(Flag(True), "the cavity pressure, the jet's thrust and the inflow"),
    'vehicle_motion': Key(Flag(True), "the vehicle's motion (false: the vehicle is held)"),
}
FLUID_SPEC = {
    'density_kg_m3': _number(None, 1.0, 20000.0, 'kg/m^3', "rho, the water's density"),
    'added_mass_coefficient': _number(1.1, 0.0, 10.0, '', 'C_a'),
    'added_mass_length_m': _number(None, 0.0, 10.0, 'm', 'l_a: added mass C_a rho l_a per area',
                                   default='half the largest radius'),
    'tangential_drag_coefficient': _number(0.05, 0.0, 10.0, '', 'C_t, on the wall'),
    'drag_coefficient': _number(1.0, 0.0, 10.0, '', 'C_d, of the vehicle'),
    'internal_inertia': Key(
        Choice('none', INTERNAL_INERTIA),
        'one_dimensional(_deforming): the water inside carries the inertia of a one-dimensional '
        'internal flow on the reference (current) shape (outlet edge, implicit integrator)',
    ),
    'internal_flow_momentum': Key(
        Flag(False), "true: that flow's momentum relative to the body too (one_dimensional)"),
}
JET_SPEC = {
    'outlet': Key(
        Choice(None, OUTLETS),
        "ring: a rigid outlet in the clamped ring; edge: the mantle's free edge is the nozzle; "
        'free_edge_fixed_nozzle: the edge free, the jet through a fixed nozzle',
        default='ring (consistent), edge (paper), free_edge_fixed_nozzle (paper_code)',
    ),
    'outlet_radius_m': _number(None, 1e-4, math.inf, 'm', "the fixed outlet's radius (not with "
                               'edge)', default="half the ring's radius (paper_code: 12.5 mm)",
                               allowed="[0.0001, the ring's radius]"),
    'inlet_area_m2': _number(None, 1e-8, 10.0, 'm^2', 'the refill opening',
                             default='outlet + 3 pi (10 mm)^2'),
    'thrust_coefficient': _number(1.0, 0.0, 2.0, '', 'C_f'),
    'contraction_coefficient': _number(
        1.0, 0.5, 1.0, '', "Cc: the outflow's vena contracta is Cc times the fixed outlet's "
        'area (1: none; a sharp-edged orifice about 0.61-0.65; docs/theory/shell.md; consistent '
        'coupling, not with outlet: edge or starting_jet)',
    ),
    'starting_jet': Key(
        Flag(False),
        "true: the forming vortex ring's exit over-pressure (consistent coupling, implicit "
        'integrator, docs/theory/starting_jet.md)',
    ),
    'formation_number': _number(FORMATION_NUMBER, *FORMATION_NUMBER_RANGE, '',
                                'the stroke ratio L/D at which the ring pinches off (with '
                                'starting_jet only)'),
}
VEHICLE_SPEC = {
    'mass_kg': _number(None, 1e-6, 1e6, 'kg', 'shell plus payload',
                       default="twice the moving shell's mass",
                       allowed="[1e-06, 1e+06], more than the moving shell's mass"),
    'added_mass_kg': _number(0.0, 0.0, 1e6, 'kg', "the body's added mass"),
    'initial_velocity_m_s': _number(0.0, -100.0, 100.0, 'm/s', 'at t = 0'),
}
ACTUATION_SPEC = {
    'kind': Key(Choice('none', ACTUATION_KINDS),
                'cable: a radial pull; muscle: the desired hoop radius lowered in time'),
    'source': Key(Choice('routine', ('routine', 'command')),
                  "routine: the scene's own; command: from pulsejet/cmd/cable_force (cable only)"),
    'amplitude': _number(None, 0.0, CABLE_FORCE_HIGH_N, '',
                         'cable: peak total radial pull, N; muscle: fractional drop of the '
                         'desired radius',
                         allowed=f'cable: [0, {CABLE_FORCE_HIGH_N:g}] N; muscle: [0, 0.95]'),
    'frequency_hz': _number(None, 0.0, 100.0, 'Hz', "the routine's frequency", low_open=True),
    'contraction_s': _number(None, 0.0, math.inf, 's', 'the rise', low_open=True,
                             allowed='(0, period], with release_s at most the period'),
    'release_s': _number(None, 0.0, math.inf, 's', 'the fall', low_open=True,
                         allowed='(0, period], with contraction_s at most the period'),
    'start_delay_s': _number(0.0, 0.0, 1e6, 's', 'rest before the first rise'),
    'pulse': Key(Choice('half_cosine', PULSE_NAMES),
                 'the rise and fall: half cosines or straight lines'),
    'distribution': Key(Choice('uniform', DISTRIBUTIONS),
                        'cable: the pull along the meridian, uniform, rising (towards the ring) '
                        'or falling (towards the pole)'),
    'max_cable_force_n': _number(None, 0.0, CABLE_FORCE_HIGH_N, 'N',
                                 "cable: the actuator's rating; a command above it is refused",
                                 low_open=True, default='twice the amplitude'),
    'taper_fraction': _number(0.15, 0.01, 0.5, '', 'muscle: the tapers at the ends, of the '
                              'meridian'),
    'desired_radius': Key(Choice('proportional', DESIRED_RADIUS),
                          'muscle: the desired radius a fraction of the rest radius, or the rest '
                          'profile moved inwards (to the edge)'),
}
#: the actuation keys each kind takes (kind none ignores the others: it is off)
ACTUATION_ROUTINE_KEYS = ('kind', 'source', 'amplitude', 'frequency_hz', 'contraction_s',
                          'release_s', 'start_delay_s', 'pulse')
ACTUATION_KIND_KEYS = {
    'cable': ACTUATION_ROUTINE_KEYS + ('distribution', 'max_cable_force_n'),
    'muscle': ACTUATION_ROUTINE_KEYS + ('taper_fraction', 'desired_radius'),
}
LOAD_SPEC = {
    'internal_pressure_pa': _number(0.0, -1e6, 1e6, 'Pa', 'a static pressure load (for tests)'),
}
INITIAL_SPEC = {
    'radial_perturbation_m': _number(0.0, -math.inf, math.inf, 'm', 'r += d sin(pi X/L) at t = 0',
                                     allowed='within half the largest radius'),
}
#: the sections of a shell scene, in the order the docs list them (geometry: GEOMETRY_SPECS)
SECTION_SPECS = {
    'simulation': SIMULATION_SPEC,
    'mesh': MESH_SPEC,
    'material': MATERIAL_SPEC,
    'fluid': FLUID_SPEC,
    'jet': JET_SPEC,
    'vehicle': VEHICLE_SPEC,
    'actuation': ACTUATION_SPEC,
    'terms': TERMS_SPEC,
    'load': LOAD_SPEC,
    'initial': INITIAL_SPEC,
}
#: the top-level keys a shell scene may hold
SECTIONS = ('model', 'name', 'description', 'coupling', 'simulation', 'geometry', 'mesh',
            'material', 'fluid', 'vehicle', 'jet', 'actuation', 'terms', 'initial', 'load')


def section(scene: Mapping[str, Any], name: str, required: bool = True) -> Mapping[str, Any]:
    """Return the mapping of section `name` ({} when absent and not required)."""
    sec = scene.get(name)
    if sec is None:
        if required:
            raise ModelError(
                f'{name}: missing section; allowed: a mapping (see config/shell_robot.yaml)'
            )
        return {}
    if not isinstance(sec, Mapping):
        raise ModelError(f'{name}: {show(sec)} is not a mapping; allowed: a mapping of parameters')
    return sec


def refuse_unknown(sec: Mapping[str, Any], where: str, allowed) -> None:
    """Refuse the first key of `sec` not in `allowed` (a spec or a tuple of names)."""
    for k in sec:
        if k not in allowed:
            raise ModelError(
                f'{where}.{show(k) if not isinstance(k, str) else k[:60]}: unknown key '
                f'(value {show(sec[k])}); allowed: {", ".join(allowed)}'
            )


def _allowed(rule: Number | Choice | Flag) -> str:
    if isinstance(rule, Choice):
        return f'one of {", ".join(rule.choices)}'
    if isinstance(rule, Flag):
        return 'true or false'
    return rule.allowed()


def read(
    sec: Mapping[str, Any],
    where: str,
    name: str,
    spec: Mapping[str, Key],
    *,
    default: Any = None,
    **narrow: Any,
) -> Any:
    """
    Return key `name` of section `where` by its rule in `spec`.

    `default` replaces the rule's (a default derived from other keys); `narrow` replaces fields
    of the rule for this scene (low, high, choices: bounds derived from other keys). Numbers come
    back as float (an int with Number.integer), choices and booleans as given.
    """
    rule = spec[name].rule
    if narrow:
        rule = replace(rule, **narrow)
    path = f'{where}.{name}' if where else name
    if name not in sec:
        value = rule.default if default is None else default
        if value is None:
            raise ModelError(f'{path}: missing; allowed: {_allowed(rule)}')
        return float(value) if isinstance(rule, Number) and not rule.integer else value
    value = sec[name]
    if isinstance(rule, Choice):
        if value not in rule.choices:  # words of the shell's refusals since its first scenes
            raise ModelError(f'{path}: {show(value)} is not known; allowed: {_allowed(rule)}')
        return value
    if isinstance(rule, Flag):
        return rule.check(path, value)
    if rule.integer:
        whole = f'a whole number in [{rule.low:g}, {rule.high:g}]'
        if isinstance(value, bool) or not isinstance(value, int):
            raise ModelError(f'{path}: {show(value)} is not a whole number; allowed: {whole}')
        rule.check(path, value, allowed=whole)
        return value
    return rule.check(path, value, from_text=True)
