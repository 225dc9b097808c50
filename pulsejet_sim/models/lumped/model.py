"""
Lumped pulsed-jet model (paper 001).

Immutable parameters compiled from a scene, plus the Model-protocol methods that drive the numba
kernels in ``lumped.kernels``.

The derivation, the choices where the paper is ambiguous and the energy ledger are in
``docs/theory/lumped.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math
from typing import Any, Mapping

import numpy as np
from pulsejet_sim.core.model_io import (
    Command,
    ModelError,
    Observation,
    SimulationBlowUp,
    VALVE_MIN_OPENING,
)
from pulsejet_sim.core.schema import check_section, Choice, Flag, Number
from pulsejet_sim.models.lumped import kernels as K
from pulsejet_sim.models.rubber import (
    neo_hookean_shear_modulus_pa,
    refuse_keys_of_other_laws,
    SILICONE_CHOICES,
)
from scipy import integrate

TERM_BITS = {
    'shell_inertia': K.T_SHELL_INERTIA,
    'internal_added_mass': K.T_INTERNAL_ADDED_MASS,
    'nozzle_inertia': K.T_NOZZLE_INERTIA,
    'viscous_loss': K.T_VISCOUS_LOSS,
    'fluid_stiffness': K.T_FLUID_STIFFNESS,
    'added_mass': K.T_ADDED_MASS,
    'added_mass_variation': K.T_ADDED_MASS_VARIATION,
    'fluid_mass': K.T_FLUID_MASS,
    'drag': K.T_DRAG,
    'jet_thrust': K.T_JET_THRUST,
}

SIMULATION_SPEC = {
    'dt_s': Number(1e-4, 1e-7, 0.1, unit='s'),
    'duration_s': Number(10.0, 0.0, 1e6, low_open=True, unit='s'),
    'publish_rate_hz': Number(100.0, 1.0, 10000.0, unit='Hz'),
    # rk4: fixed step dt_s (with stability sub-steps), what HIL and bit-exact replays use;
    # adaptive: Dormand-Prince 5(4) with error control (rtol, atol) and dense output; dt_s is then
    # only the time grid of Simulation.step (lumped.kernels, "adaptive")
    'integrator': Choice('rk4', ('rk4', 'adaptive')),
    'rtol': Number(1e-6, 1e-13, 1e-2, unit='(relative tolerance, adaptive only)'),
    'atol': Number(1e-9, 1e-16, 1e-2, unit='(absolute tolerance, adaptive only)'),
}
GEOMETRY_SPEC = {
    'length_m': Number(0.36, 0.0, 10.0, low_open=True, unit='m'),
    'rest_minor_semi_axis_m': Number(None, 0.0, 5.0, low_open=True, unit='m'),
    'initial_minor_semi_axis_m': Number(None, 0.0, 5.0, low_open=True, unit='m'),
    'nozzle_radius_m': Number(0.022, 0.0, 1.0, low_open=True, unit='m'),
    'nozzle_length_m': Number(0.036, 0.0, 1.0, low_open=True, unit='m'),
    'nozzle_inlet_position': Number(0.82, -0.99, 0.99, unit='(x_e, fraction of a)'),
    'solid_volume_m3': Number(0.0, 0.0, 1.0, unit='m^3'),
}
SHELL_LAWS = ('linear', 'neo_hookean', 'mooney_rivlin')
MATERIAL_SPEC = {
    # the shell's elastic law: 'linear' = the spring k (b - b0) of paper 001 (stiffness_n_m);
    # 'neo_hookean' / 'mooney_rivlin' = the strain energy of an incompressible rubber membrane of
    # thickness shell_thickness_m on the rest ellipsoid (docs/theory/hyperelastic.md)
    'law': Choice('linear', SHELL_LAWS),
    'stiffness_n_m': Number(None, 0.0, 1e9, low_open=True, unit='N/m'),
    # neo_hookean: a tabled silicone (models/rubber.py, with its source) or mu itself
    'silicone': Choice('none', SILICONE_CHOICES),
    'shear_modulus_pa': Number(0.0, 0.0, 1e10, low_open=True, unit='Pa'),
    # mooney_rivlin: W = C1 (I1 - 3) + C2 (I2 - 3)
    'mooney_rivlin_c1_pa': Number(0.0, 0.0, 1e10, low_open=True, unit='Pa'),
    'mooney_rivlin_c2_pa': Number(0.0, 0.0, 1e10, unit='Pa'),
    'shell_thickness_m': Number(None, 0.0, 1.0, low_open=True, unit='m'),
    'density_kg_m3': Number(1100.0, 0.0, 1e5, low_open=True, unit='kg/m^3'),
    'payload_mass_kg': Number(0.0, 0.0, 1e4, unit='kg'),
}
FLUID_SPEC = {
    'density_kg_m3': Number(1000.0, 1.0, 2e4, unit='kg/m^3'),
    'viscosity_pa_s': Number(1.0e-3, 0.0, 10.0, unit='Pa s'),
    'drag_coefficient': Number(0.1, 0.0, 10.0, unit=''),
    'inlet_loss_coefficient': Number(0.5, 0.0, 10.0, unit=''),
}
ACTUATOR_SPEC = {
    'pump_time_constant_s': Number(0.05, 1e-4, 10.0, unit='s'),
    # the pump's relief and stall pressures, Pa; default (-1): the shell's elastic pressure at
    # b = 0.8 a and 0.9 a, so no command inflates the shell past its bound
    'pump_relief_pressure_pa': Number(-1.0, -1.0, 1e7, unit='Pa'),
    'pump_stall_pressure_pa': Number(-1.0, -1.0, 1e7, unit='Pa'),
    'valve_stroke_time_s': Number(0.05, 1e-4, 10.0, unit='s'),
    'initial_pump_flow_m3_s': Number(0.0, 0.0, Command.LIMITS['pump_flow_m3_s'][1], unit='m^3/s'),
    'initial_valve_opening': Number(1.0, 0.0, 1.0, unit=''),
}
TERMS_SPEC = {name: Flag(True) for name in TERM_BITS}
COUPLINGS = ('consistent', 'paper')


@dataclass(frozen=True)
class DeprecatedAlias:
    """An optional key that stands for another one (old scenes, e.g. in recordings, still load)."""

    of: str
    choices: tuple[str, ...]
    default: str = ''  # '' = not given

    def check(self, key: str, value: Any) -> str:
        return Choice(None, self.choices).check(key, value)


OPTIONS_SPEC = {
    # how the shell and the vehicle are coupled: 'paper' = eqs. (1) and (3) of paper 001 as
    # written, 'consistent' = the energy-consistent coupling (docs/theory/lumped.md)
    'coupling': Choice('consistent', COUPLINGS),
    'energy_model': DeprecatedAlias('coupling', COUPLINGS),  # deprecated name of 'coupling'
    'added_mass_form': Choice('exact', ('exact', 'simplified')),
    'simplified_added_mass_coefficient': Number(0.45, 0.0, 10.0, unit=''),
    # the nozzle's section: 'rigid' = pi r_n^2; 'shell' = pi r_n^2 (b/b0)^2, the section of the
    # ellipsoid at the nozzle inlet plane x_e that paper 001's eq. 8 writes A(x_e) (reading G,
    # docs/theory/lumped.md); r_n is then the nozzle's radius at rest
    'nozzle_section': Choice('rigid', ('rigid', 'shell')),
}
SECTION_SPECS = {
    'simulation': SIMULATION_SPEC,
    'geometry': GEOMETRY_SPEC,
    'material': MATERIAL_SPEC,
    'fluid': FLUID_SPEC,
    'actuator': ACTUATOR_SPEC,
    'terms': TERMS_SPEC,
    'options': OPTIONS_SPEC,
}

_BLOWUP_CAUSES = {
    K.ERR_NONFINITE: 'a state value became non-finite',
    K.ERR_B_LOW: 'the minor semi-axis collapsed below its bound',
    K.ERR_B_HIGH: 'the minor semi-axis grew beyond the major semi-axis',
    K.ERR_SPEED: 'the vehicle speed exceeded its bound',
    K.ERR_SUBSTEPS: 'the step needs more sub-steps than allowed (stiffness out of range)',
}


# the material keys each law takes (the others are refused when given, never ignored)
_LAW_KEYS = {
    'linear': ('stiffness_n_m',),
    'neo_hookean': ('silicone', 'shear_modulus_pa'),
    'mooney_rivlin': ('mooney_rivlin_c1_pa', 'mooney_rivlin_c2_pa'),
}


def check_material(given: Any) -> tuple[dict[str, Any], float, float]:
    """
    Validate the material section for its law; return it with the membrane's (C1, C2), Pa.

    (C1, C2) are (0, 0) for the linear spring. Raises ModelError naming the key.
    """
    law = 'linear'
    if isinstance(given, Mapping) and 'law' in given:
        law = MATERIAL_SPEC['law'].check('material.law', given['law'])
    spec = MATERIAL_SPEC
    if law != 'linear':  # no spring: stiffness_n_m is not needed (and refused below)
        spec = {**MATERIAL_SPEC, 'stiffness_n_m': Number(0.0, 0.0, 1e9, unit='N/m')}
    m = check_section('material', given, spec)
    given = given or {}
    refuse_keys_of_other_laws(given, law, _LAW_KEYS)
    if law == 'linear':
        return m, 0.0, 0.0
    if law == 'neo_hookean':
        mu = neo_hookean_shear_modulus_pa(given, m['silicone'], m['shear_modulus_pa'])
        return m, 0.5 * mu, 0.0
    if 'mooney_rivlin_c1_pa' not in given:
        raise ModelError(
            'material.mooney_rivlin_c1_pa: missing; allowed: '
            f'{MATERIAL_SPEC["mooney_rivlin_c1_pa"].allowed()} (material.law mooney_rivlin)'
        )
    return m, m['mooney_rivlin_c1_pa'], m['mooney_rivlin_c2_pa']


def internal_added_mass_kg(rho: float, a: float, x_e: float) -> float:
    """Paper's eq. 7: m_b = 4 pi/9 rho a^3 int_{-1}^{x_e} (1+x)^3 (2-x)^2 / (1-x) dx."""
    value, _ = integrate.quad(lambda x: (1 + x) ** 3 * (2 - x) ** 2 / (1 - x), -1.0, x_e)
    return 4.0 * math.pi / 9.0 * rho * a**3 * value


def spheroid_area_m2(a: float, b: float) -> float:
    """Surface of a prolate spheroid with semi-axes a >= b."""
    e = math.sqrt(1.0 - (b / a) ** 2)
    return 2.0 * math.pi * b * b * (1.0 + a / (b * e) * math.asin(e))


def wall_inertia_kg(rho_s: float, thickness: float, a: float, b: float) -> float:
    """
    Return the kinetic energy of the wall over b'^2/2 when every section radius R scales with b.

    I_b = rho_s t int (R/b)^2 dS, taken at the rest shape (the wall is light next to m_b).
    """

    def integrand(x):
        r = b * math.sqrt(max(1.0 - x * x / (a * a), 0.0))
        drdx = -b * x / (a * a * math.sqrt(max(1.0 - x * x / (a * a), 1e-300)))
        return (1.0 - x * x / (a * a)) * 2.0 * math.pi * r * math.sqrt(1.0 + drdx * drdx)

    value, _ = integrate.quad(integrand, -a, a, limit=200)
    return rho_s * thickness * value


def _checked_sections(
    scene: Mapping[str, Any]
) -> tuple[dict[str, dict[str, Any]], tuple[float, float]]:
    """
    Return every section checked (SECTION_SPECS; material by check_material), defaults filled in.

    Also the rubber's Mooney-Rivlin constants (C1, C2) in Pa, 0 for the linear spring.
    """
    unknown = [k for k in scene if k != 'model' and k not in SECTION_SPECS]
    if unknown:
        raise ModelError(
            f'{unknown[0]}: unknown section for the lumped model; allowed: model, name, '
            f'description, routine, {", ".join(SECTION_SPECS)}'
        )
    sections = {
        name: check_section(name, scene.get(name), spec)
        for name, spec in SECTION_SPECS.items()
        if name != 'material'
    }
    sections['material'], rubber_c1, rubber_c2 = check_material(scene.get('material'))
    return sections, (rubber_c1, rubber_c2)


def _check_valve_seat(opening: float) -> None:
    """Refuse an initial opening below the valve's seat (model_io.VALVE_MIN_OPENING), not 0."""
    if 0.0 < opening < VALVE_MIN_OPENING:
        raise ModelError(
            f'actuator.initial_valve_opening: {opening!r} is out of '
            'range; '
            f'allowed: 0 (shut) or a finite number in [{VALVE_MIN_OPENING:g}, 1]'
        )


def _resolve_coupling(opts: dict[str, Any], given_options: Mapping[str, Any]) -> None:
    """Set options.coupling from its deprecated name energy_model (in place), refusing a clash."""
    if opts['energy_model']:
        if 'coupling' in given_options and opts['coupling'] != opts['energy_model']:
            raise ModelError(
                f'options.energy_model: {opts["energy_model"]!r} contradicts '
                'options.coupling: '
                f'{opts["coupling"]!r}; allowed: only options.coupling (energy_model is its '
                f'deprecated name), or both with the same value'
            )
        opts['coupling'] = opts['energy_model']
    opts['energy_model'] = opts['coupling']


def _check_prolate(g: Mapping[str, Any]) -> None:
    """Refuse a rest or initial minor semi-axis that is not well below the major one (0.95 a)."""
    a = g['length_m'] / 2.0
    for key in ('rest_minor_semi_axis_m', 'initial_minor_semi_axis_m'):
        value = g[key]
        if value >= 0.95 * a:
            raise ModelError(
                f'geometry.{key}: {value!r} m is not a prolate ellipsoid; allowed: '
                f'below 0.95 x the major semi-axis ({0.95 * a:g} m)'
            )


def _parameter_vector(g, m, f, act, opts, rubber: tuple[float, float]) -> np.ndarray:
    """
    Pack the checked sections into the kernels' parameter vector (K.P_*, SI).

    rubber: the membrane's Mooney-Rivlin (C1, C2), Pa, with material.law neo_hookean or
    mooney_rivlin (theory/hyperelastic.md).

    Derived values: the shell's mass and wall inertia from its surface, the internal added mass
    (eq. 7), the nozzle's section, the bounds the kernels stop at, the pump's pressures.
    """
    a = g['length_m'] / 2.0
    b0 = g['rest_minor_semi_axis_m']
    rho = f['density_kg_m3']
    r_n = g['nozzle_radius_m']
    p = np.zeros(K.NP)
    p[K.P_RHO] = rho
    p[K.P_MU] = f['viscosity_pa_s']
    p[K.P_A] = a
    p[K.P_B0] = b0
    p[K.P_K] = m['stiffness_n_m']
    if m['law'] != 'linear':
        p[K.P_MR_C1], p[K.P_MR_C2] = rubber
        p[K.P_MEMBRANE_THICKNESS] = m['shell_thickness_m']
        # no spring: P_K holds the membrane's tangent stiffness at rest (for k_x/k only)
        p[K.P_K] = K.membrane_spheroid(
            a, b0, a, b0, rubber[0], rubber[1], m['shell_thickness_m']
        )[3]
    p[K.P_M_SOLID] = (
        m['density_kg_m3'] * spheroid_area_m2(a, b0) * m['shell_thickness_m']
        + m['payload_mass_kg']
    )
    p[K.P_I_B] = wall_inertia_kg(m['density_kg_m3'], m['shell_thickness_m'], a, b0)
    p[K.P_M_B] = internal_added_mass_kg(rho, a, g['nozzle_inlet_position'])
    p[K.P_L_N] = g['nozzle_length_m']
    p[K.P_A_N] = math.pi * r_n * r_n
    p[K.P_D_N] = 2.0 * r_n
    p[K.P_K_INLET] = f['inlet_loss_coefficient']
    p[K.P_CD] = f['drag_coefficient']
    p[K.P_V_SOLID] = g['solid_volume_m3']
    p[K.P_C1] = opts['simplified_added_mass_coefficient']
    p[K.P_PUMP_TAU] = act['pump_time_constant_s']
    p[K.P_VALVE_RATE] = 1.0 / act['valve_stroke_time_s']
    p[K.P_B_MIN] = 0.02 * b0
    p[K.P_B_MAX] = 0.999 * a
    p[K.P_U_MAX] = 100.0
    relief, stall = _pump_pressures_pa(act, m, a, b0, rubber)
    p[K.P_NOZZLE_SECTION] = math.pi * r_n * r_n / (b0 * b0)
    p[K.P_P_RELIEF] = relief
    p[K.P_P_STALL] = stall
    if g['solid_volume_m3'] >= 4.0 / 3.0 * math.pi * a * b0 * b0:
        raise ModelError(
            f'geometry.solid_volume_m3: {g["solid_volume_m3"]!r} m^3 fills the rest cavity; '
            f'allowed: below {4.0 / 3.0 * math.pi * a * b0 * b0:.4g} m^3'
        )
    return p


def _pump_pressures_pa(
    act: Mapping[str, Any], m: Mapping[str, Any], a: float, b0: float, rubber: tuple[float, float]
) -> tuple[float, float]:
    """
    Return the pump's (relief, stall) pressures, Pa; -1 given: the shell's at b = 0.8 a and 0.9 a.

    The stall pressure may not exceed the shell's elastic pressure at b = 0.95 a: a stronger pump
    would inflate the shell past the bound the kernels stop at.
    """

    def elastic_pressure(b_m):  # k (b - b0) / (dV/db) or dU/db / (dV/db), Pa
        if m['law'] != 'linear':
            force = K.membrane_spheroid(
                a, b0, a, b_m, rubber[0], rubber[1], m['shell_thickness_m']
            )[2]
            return force / (8.0 / 3.0 * math.pi * a * b_m)
        return m['stiffness_n_m'] * (b_m - b0) / (8.0 / 3.0 * math.pi * a * b_m)

    relief = act['pump_relief_pressure_pa']
    stall = act['pump_stall_pressure_pa']
    relief = elastic_pressure(0.8 * a) if relief < 0 else relief
    stall = elastic_pressure(0.9 * a) if stall < 0 else stall
    limit = elastic_pressure(0.95 * a)
    if not relief < stall <= limit:
        raise ModelError(
            f'actuator.pump_stall_pressure_pa: {stall!r} Pa with relief {relief!r} Pa; '
            'allowed: '
            f'relief < stall <= {limit:.6g} Pa (the elastic pressure of the shell at b = 0.95 '
            'a: a '
            f'stronger pump inflates it past its bound), or -1 for the defaults'
        )
    return relief, stall


def _term_and_option_flags(
    terms: Mapping[str, bool], opts: Mapping[str, Any], law: str
) -> int:
    """Return the kernels' bit flags: one bit per switched-on term (TERM_BITS) and option."""
    flags = 0
    for name, bit in TERM_BITS.items():
        if terms[name]:
            flags |= bit
    if opts['coupling'] == 'consistent':
        flags |= K.O_COUPLING_CONSISTENT
    if opts['added_mass_form'] == 'simplified':
        flags |= K.O_ADDED_MASS_SIMPLIFIED
    if opts['nozzle_section'] == 'shell':
        flags |= K.O_NOZZLE_FOLLOWS_SHELL
    if law != 'linear':
        flags |= K.O_HYPERELASTIC
    return flags


# ---- named readings of the kernels' vectors (SI) ------------------------------------------------
# Environments and studies read the parameter and state vectors through these, not through the
# kernels' slot numbers (K.P_*, K.Y_*), so a change of the vectors' layout stays inside this model.
# Each takes one vector or a batch of them along the last axis (the vector environment steps many
# robots at once) and returns numpy values; the volume formulas keep the kernels' operation order,
# so the numbers are the same bits the kernels compute.


def position_m(state: np.ndarray):
    """Return the vehicle's position x, m (positive forward)."""
    return state[..., K.Y_X]


def velocity_m_s(state: np.ndarray):
    """Return the vehicle's forward velocity U, m/s."""
    return state[..., K.Y_U]


def minor_semi_axis_m(state: np.ndarray):
    """Return the shell's minor semi-axis b, m."""
    return state[..., K.Y_B]


def minor_semi_axis_rate_m_s(state: np.ndarray):
    """Return db/dt, m/s."""
    return state[..., K.Y_W]


def pump_flow_m3_s(state: np.ndarray):
    """Return the pump's actual flow (lagging its command), m^3/s."""
    return state[..., K.Y_QP]


def valve_opening(state: np.ndarray):
    """Return the valve's actual opening, 0 (shut) .. 1."""
    return state[..., K.Y_VALVE]


def pump_work_j(state: np.ndarray):
    """Return the actuation work the pump has put in since the start, J (in_actuation_work)."""
    return state[..., K.Y_W_PUMP]


def major_semi_axis_m(params: np.ndarray):
    """Return the shell's major semi-axis a (half its length), m."""
    return params[..., K.P_A]


def minor_semi_axis_bounds_m(params: np.ndarray):
    """Return (b_min, b_max), m: the minor semi-axes the model accepts before it stops."""
    return params[..., K.P_B_MIN], params[..., K.P_B_MAX]


def speed_bound_m_s(params: np.ndarray):
    """Return the bound of |U| the model accepts before it stops, m/s."""
    return params[..., K.P_U_MAX]


def solid_volume_m3(params: np.ndarray):
    """Return the volume inside the shell that water does not fill, m^3."""
    return params[..., K.P_V_SOLID]


def dry_mass_kg(params: np.ndarray):
    """Return the shell plus payload mass, kg (no water)."""
    return params[..., K.P_M_SOLID]


def cavity_volume_m3(state: np.ndarray, params: np.ndarray):
    """Return the water volume in the cavity, 4/3 pi a b^2 - V_solid, m^3."""
    b = state[..., K.Y_B]
    return 4.0 / 3.0 * math.pi * params[..., K.P_A] * b * b - params[..., K.P_V_SOLID]


def rest_cavity_water_kg(params: np.ndarray):
    """Return the water mass of the cavity at rest, rho (4/3 pi a b0^2 - V_solid), kg."""
    rest = 4.0 / 3.0 * math.pi * params[..., K.P_A] * params[..., K.P_B0] ** 2 - params[
        ..., K.P_V_SOLID
    ]
    return params[..., K.P_RHO] * rest


def scale_minor_semi_axis(state: np.ndarray, params: np.ndarray, factor: float) -> None:
    """
    Scale b of one state vector in place by `factor` (a perturbed initial shape).

    A shut valve's cavity moves only with the pump, so db/dt is then set to Q_p / (dV/db), dV/db
    = 8/3 pi a b, as initial_state does.
    """
    state[K.Y_B] *= factor
    if state[K.Y_VALVE] <= 0.0:
        state[K.Y_W] = state[K.Y_QP] / (8.0 / 3.0 * math.pi * params[K.P_A] * state[K.Y_B])


@dataclass(frozen=True)
class LumpedModel:
    """Immutable compiled lumped model; the mutable state lives in a numpy vector."""

    params: np.ndarray
    flags: int
    dt_s: float
    initial_b_m: float
    initial_command: Command
    terms: frozenset
    options: Mapping[str, Any]
    name: str = 'lumped'
    shell_law: str = 'linear'  # material.law: the linear spring or a rubber membrane
    integrator: str = 'rk4'
    rtol: float = 1e-6
    atol: float = 1e-9

    @classmethod
    def from_scene(cls, scene: Mapping[str, Any]) -> 'LumpedModel':
        """
        Compile a scene mapping: check every section, then pack the kernels' vectors.

        Raises ModelError naming the key, the value and what is allowed.
        """
        sections, rubber = _checked_sections(scene)
        act, terms, opts = sections['actuator'], sections['terms'], sections['options']
        _check_valve_seat(act['initial_valve_opening'])
        _resolve_coupling(opts, scene.get('options') or {})
        _check_prolate(sections['geometry'])
        if not (terms['shell_inertia'] or terms['internal_added_mass'] or terms['nozzle_inertia']):
            raise ModelError(
                'terms: shell_inertia, internal_added_mass and nozzle_inertia are all false; '
                'allowed: at least one of them true (the shell needs inertia)'
            )
        p = _parameter_vector(
            sections['geometry'], sections['material'], sections['fluid'], act, opts, rubber
        )
        p.setflags(write=False)
        command = Command(act['initial_pump_flow_m3_s'], act['initial_valve_opening'], 0.0)
        sim = sections['simulation']
        return cls(
            params=p,
            flags=_term_and_option_flags(terms, opts, sections['material']['law']),
            dt_s=sim['dt_s'],
            initial_b_m=sections['geometry']['initial_minor_semi_axis_m'],
            initial_command=command,
            terms=frozenset(n for n in TERM_BITS if terms[n]),
            options=dict(opts),
            shell_law=sections['material']['law'],
            integrator=sim['integrator'],
            rtol=sim['rtol'],
            atol=sim['atol'],
        )

    @property
    def dry_mass_kg(self) -> float:
        """Shell plus payload mass, kg (no water)."""
        return float(self.params[K.P_M_SOLID])

    # ---- Model protocol ------------------------------------------------------------------------
    def initial_state(self) -> np.ndarray:
        y = np.zeros(K.NY)
        y[K.Y_B] = self.initial_b_m
        y[K.Y_QP] = self.initial_command.pump_flow_m3_s
        y[K.Y_VALVE] = self.initial_command.valve_opening
        if y[K.Y_VALVE] <= 0.0:
            # a sealed cavity moves only with the pump
            y[K.Y_W] = y[K.Y_QP] / (8.0 / 3.0 * math.pi * self.params[K.P_A] * self.initial_b_m)
        if self.integrator == 'adaptive':
            # the step-size controller's memory travels with the state (K.M_*), after the NY slots
            mem = np.zeros(K.NMEM)
            mem[K.M_Q] = mem[K.M_VALVE] = (
                np.nan
            )  # no previous command: the first call starts afresh
            y = np.concatenate([y, mem])
        return y

    def advance(self, state: np.ndarray, time_s: float, n_steps: int, command: Command) -> int:
        if self.integrator == 'adaptive':
            if n_steps <= 0:
                return 0
            self.advance_dense(state, time_s, n_steps * self.dt_s, command)
            return int(n_steps)
        return self._advance_rk4(state, time_s, n_steps, command)

    def advance_dense(
        self,
        state: np.ndarray,
        time_s: float,
        duration_s: float,
        command: Command,
        t_out: np.ndarray | None = None,
        rtol: float | None = None,
        atol: float | None = None,
    ):
        """
        Advance `state` (in place) by duration_s holding `command` with the adaptive integrator.

        Returns (states at time_s + t_out, stats): t_out increasing offsets in (0, duration_s] (the
        publication times), the states by the integrator's dense output, one row each (K.NY
        columns); stats: accepted and rejected steps, right-hand-side evaluations (K.S_*). Works on
        an rk4 model's state too (its controller then starts afresh every call). Raises
        SimulationBlowUp with the state at the last accepted step.
        """
        t_out = np.empty(0) if t_out is None else np.ascontiguousarray(t_out, dtype=float)
        out = np.empty((t_out.shape[0], K.NY))
        stats = np.zeros(K.NSTATS)
        if state.shape[0] >= K.NY + K.NMEM:
            y = state[: K.NY]
            mem = state[K.NY: K.NY + K.NMEM]
        else:
            y = state
            mem = np.zeros(K.NMEM)
            mem[K.M_Q] = mem[K.M_VALVE] = np.nan
        args = (
            y,
            mem,
            self.params,
            float(command.pump_flow_m3_s),
            float(command.valve_opening),
            float(duration_s),
            float(self.rtol if rtol is None else rtol),
            float(self.atol if atol is None else atol),
            t_out,
            out,
            stats,
        )
        # the first call per term set compiles (or loads) the specialisation on a zero-length copy
        warm = (
            y.copy(),
            mem.copy(),
            *args[2:5],
            0.0,
            *args[6:8],
            np.empty(0),
            np.empty((0, K.NY)),
            np.zeros(K.NSTATS),
        )
        status, written = K.specialised(K.adaptive_advance, self.flags, *warm)(self.flags, *args)
        if status != K.OK:
            t_fail = time_s + stats[K.S_T_DONE]
            raise SimulationBlowUp(
                f'lumped model (adaptive) stopped at t={t_fail:.6f} s: {_BLOWUP_CAUSES[status]} '
                f'(b={y[K.Y_B]:.6g} m, db/dt={y[K.Y_W]:.6g} m/s, U={y[K.Y_U]:.6g} m/s); '
                f'the state is kept at the last accepted step',
                t_fail,
            )
        return out[:written], stats

    def _advance_rk4(
        self, state: np.ndarray, time_s: float, n_steps: int, command: Command
    ) -> int:
        args = (
            state,
            self.params,
            float(command.pump_flow_m3_s),
            float(command.valve_opening),
            int(n_steps),
            self.dt_s,
        )
        done, status = (
            K.specialised(K.advance, self.flags, *args[:4], 0, self.dt_s)(self.flags, *args)
            if n_steps > 0
            else (0, K.OK)
        )
        if status != K.OK:
            t_fail = time_s + (done + 1) * self.dt_s
            raise SimulationBlowUp(
                f'lumped model stopped at t={t_fail:.6f} s: {_BLOWUP_CAUSES[status]} '
                f'(b={state[K.Y_B]:.6g} m, db/dt={state[K.Y_W]:.6g} m/s, U={state[K.Y_U]:.6g} '
                'm/s); '
                f'the state is kept at the last good step',
                time_s + done * self.dt_s,
            )
        return done

    def diagnostics(self, state: np.ndarray, command: Command) -> np.ndarray:
        diag = np.empty(K.ND)
        K.specialised(K.evaluate, self.flags, state, self.params, 0.0, diag)(
            self.flags, state, self.params, float(command.pump_flow_m3_s), diag
        )
        return diag

    def observe(self, state: np.ndarray, time_s: float, command: Command) -> Observation:
        d = self.diagnostics(state, command)
        p = self.params
        b = state[K.Y_B]
        volume = 4.0 / 3.0 * math.pi * p[K.P_A] * b * b - p[K.P_V_SOLID]
        return Observation(
            time_s=time_s,
            position_m=float(state[K.Y_X]),
            velocity_m_s=float(state[K.Y_U]),
            acceleration_m_s2=float(d[K.D_ACCEL]),
            mantle_radius_m=float(b),
            volume_m3=float(volume),
            fluid_mass_kg=float(p[K.P_RHO] * volume),
            thrust_n=float(d[K.D_THRUST]),
            added_mass_force_n=float(d[K.D_AMV_FORCE]),
            drag_n=float(d[K.D_DRAG]),
            jet_speed_m_s=float(d[K.D_Q_N] / d[K.D_A_N]) if state[K.Y_VALVE] > 0 else 0.0,
            cavity_pressure_pa=float(d[K.D_P_CAV]),
            pump_flow_m3_s=float(state[K.Y_QP]),
            valve_opening=float(state[K.Y_VALVE]),
        )

    def stored_energy(self, state: np.ndarray) -> tuple[float, float, float, float]:
        diag = np.empty(K.ND)
        return K.specialised(K.evaluate, self.flags, state, self.params, 0.0, diag)(
            self.flags, state, self.params, 0.0, diag
        )

    def energy_ledger(
        self, state: np.ndarray, initial_state: np.ndarray | None = None
    ) -> dict[str, float]:
        """
        Return the energy books, J.

        ``created_*``: energy the applied equations create beyond the energy-consistent ones
        (negative: destroy), each the integral of (applied - consistent generalised force) x its
        velocity; never an input. closure = stored - in + out - created.
        """
        if initial_state is None:
            initial_state = self.initial_state()
        elastic, vehicle, outer, internal = self.stored_energy(state)
        e0 = sum(self.stored_energy(initial_state))
        out_other = state[K.Y_E_VALVE] + state[K.Y_E_MIX]
        created = {
            'created_fluid_stiffness': state[K.Y_C_KX],
            'created_unpaid_jet_kinetic': state[K.Y_C_JET],
            'created_nozzle_mass_variation': state[K.Y_C_NOZZLE],
            'created_unpaid_added_mass_thrust': state[K.Y_C_AMV],
            'created_unpaid_inflow_momentum': state[K.Y_C_RAM],
        }
        ledger = {
            'stored_elastic': elastic,
            'stored_kinetic_vehicle': vehicle,
            'stored_kinetic_outer_fluid': outer,
            'stored_kinetic_internal': internal,
            'in_initial': e0,
            'in_actuation_work': state[K.Y_W_PUMP],
            'out_jet_kinetic': state[K.Y_E_JET],
            'out_drag': state[K.Y_E_DRAG],
            'out_viscous': state[K.Y_E_VISC],
            'out_valve': state[K.Y_E_VALVE],
            'out_inflow_mixing': state[K.Y_E_MIX],
            'out_other': out_other,
            **created,
        }
        created_total = sum(created.values())
        stored = elastic + vehicle + outer + internal
        out = state[K.Y_E_JET] + state[K.Y_E_DRAG] + state[K.Y_E_VISC] + out_other
        closure = stored - e0 - state[K.Y_W_PUMP] + out - created_total
        ledger['closure_error'] = closure
        ledger['closure_relative'] = closure / max(e0 + abs(state[K.Y_W_PUMP]), 1e-12)
        return {k: float(v) for k, v in ledger.items()}

    def profile(self, state: np.ndarray):
        """Meridian of the ellipsoid (r, z), z from bow (+a) to stern (-a)."""
        z, shape = self._meridian
        return state[K.Y_B] * shape, z.copy()

    def profile_sample(self, state: np.ndarray) -> np.ndarray:
        """Return the part of ``state`` profile() reads (a view): the minor semi-axis b."""
        return state[K.Y_B:K.Y_B + 1]

    def profiles_of_samples(self, samples: np.ndarray):
        """Return profile() of many states from profile_sample rows: (r_m, z_m), (n, 41) each."""
        z, shape = self._meridian
        return samples[:, :1] * shape, np.broadcast_to(z, (len(samples), len(z)))

    @functools.cached_property
    def _meridian(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the 41 stations z and r/b there (a is fixed: only b scales a profile)."""
        a = self.params[K.P_A]
        z = np.linspace(a, -a, 41)
        return z, np.sqrt(np.clip(1.0 - (z / a) ** 2, 0.0, None))

    def stable_step_s(self, state: np.ndarray) -> float:
        """Largest step RK4 keeps stable without sub-steps at this state."""
        d = self.diagnostics(state, Command(float(state[K.Y_QP]), float(state[K.Y_VALVE]), 0.0))
        rate = max(d[K.D_DAMPING_RATE], d[K.D_SPRING_RATE], 1e-12)
        return K.RK4_STABLE_REAL / rate

    # ---- figures the paper reports -------------------------------------------------------------
    def fluid_stiffness_ratio(self, state: np.ndarray) -> float:
        """
        Return k_x / k at this state (paper's Fig. 6).

        k_x from section 3.5 / eq. 10 in both couplings (applied as k_x b only in the paper
        coupling).
        """
        _, k_x = K.fluid_stiffness_force(state[K.Y_B], state[K.Y_U], self.params)
        return float(k_x / self.params[K.P_K])
