"""
The shell's rubber wall (material.law neo_hookean): kernel, scene keys, balloon, ledger.

What each test checks: the membrane energy's closed form against the stretch form, its resultants
and the muscle's active force against the energy's own derivatives, the small-strain limit (the
linear law with E = 3 mu, nu = 1/2, compared in the kernel, where nu = 1/2 can be given), the
scene keys' refusals, a hemisphere inflated to rest against the neo-Hookean spherical balloon's
pressure-stretch law and its pressure maximum, and the energy ledger's closure at the
integrator's order (free oscillation in the nonlinear range, the cable robot and the muscle-driven
cone). Theory: docs/theory/shell_rubber.md.
"""

import copy
import math
import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError, SimulationBlowUp
from pulsejet_sim.core.schema import read_yaml_file
from pulsejet_sim.models.rubber import (
    neo_hookean_balloon_peak_pressure_pa,
    NEO_HOOKEAN_BALLOON_PEAK_STRETCH,
    SILICONES,
    spherical_balloon_pressure_pa,
)
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.model import ShellModel
import pytest

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
MU_H = 40.0  # mu h, N/m (mu = 40 kPa / 3, h = 3 mm)


def membrane_by_stretches(e11, e22, taud, mu_h):
    """W = mu h (l1^2 + l2^2 + 1/(l1^2 l2^2) - 3), l1^2 = 1 + 2 e11, l2 = tau/tau_d."""
    a = 1.0 + 2.0 * e11
    b = (taud * taud + 2.0 * e22) / (taud * taud)
    return mu_h * (a + b + 1.0 / (a * b) - 3.0)


STRAINS = [(0.3, -0.2, 1.0), (-0.15, 0.6, 1.0), (0.05, 0.02, 0.8), (0.4, 0.1, 0.75)]


@pytest.mark.parametrize('e11, e22, taud', STRAINS)
def test_membrane_energy_is_the_neo_hookean_sheet_and_resultants_its_derivatives(e11, e22, taud):
    n11, n22, w, active = sk.neo_hookean_membrane(e11, e22, taud, MU_H)
    assert w == pytest.approx(membrane_by_stretches(e11, e22, taud, MU_H), rel=1e-12)
    d = 1e-6

    def energy(a, b, t):
        return sk.neo_hookean_membrane(a, b, t, MU_H)[2]

    assert n11 == pytest.approx((energy(e11 + d, e22, taud) - energy(e11 - d, e22, taud))
                                / (2 * d), rel=1e-7)
    assert n22 == pytest.approx((energy(e11, e22 + d, taud) - energy(e11, e22 - d, taud))
                                / (2 * d), rel=1e-7)
    # the muscle's active force: -dW/dtau_d at fixed positions (fixed tau, so e22 moves with
    # tau_d: e22 = (tau^2 - tau_d^2)/2)
    tau2 = 2.0 * e22 + taud * taud

    def at_fixed_tau(t):
        return energy(e11, 0.5 * (tau2 - t * t), t)

    assert active == pytest.approx(-(at_fixed_tau(taud + d) - at_fixed_tau(taud - d)) / (2 * d),
                                   rel=1e-7)


def element_inputs(strain):
    """One wall element, scaled by 1 + `strain` (both stretches); P at E = 3 mu, nu = 1/2."""
    ds, r0m, th = 2e-3, 0.03, -1.0
    E = np.zeros(sk.N_ECOLS)
    E[sk.E_DS], E[sk.E_R0M], E[sk.E_LAM0], E[sk.E_AREA] = ds, r0m, 1.0, 2 * math.pi * r0m * ds
    E[sk.E_VS0] = math.sin(th) / r0m
    c, s, scale = 0.5 * ds * math.cos(th), 0.5 * ds * math.sin(th), 1.0 + strain
    q6 = np.array([scale * (r0m - c), -scale * s, th, scale * (r0m + c), scale * s, th])
    h, mu, nu = 1e-3, 40e3 / 3, 0.5
    P = np.zeros(sk.N_PARAMS)
    P[sk.P_PSI] = 2 * 3 * mu * h / (1 - nu**2)
    P[sk.P_JS] = h * h / 3
    P[sk.P_GS] = 2 * h * mu
    P[sk.P_NU] = nu
    return q6, E, P


def test_small_strain_limit_is_the_linear_law_with_e_3_mu_and_nu_one_half():
    """
    Same element, same P (E = 3 mu, nu = 1/2): the forces differ by O(strain) relatively.

    nu = 1/2 is the incompressible limit, which the scene refuses for the linear law (its bound
    is 0.49, where Psi = 2 E h/(1 - nu^2) stays finite and the membrane is nearly
    incompressible); the kernel takes it, so the two laws are compared there.
    """
    rel = []
    for strain in (1e-3, 1e-4, 1e-5):
        q6, E, P = element_inputs(strain)
        forces = []
        for flags in (0, sk.F_NEO_HOOKEAN):
            f6, out, B = np.empty(6), np.empty(3), np.empty((5, 6))
            sk.element_force(flags, q6, np.zeros(6), E, 1.0, P, B, f6, out)
            forces.append((f6.copy(), out[0]))
        (f_lin, w_lin), (f_neo, w_neo) = forces
        rel.append(np.max(np.abs(f_neo - f_lin)) / np.max(np.abs(f_lin)))
        assert w_neo == pytest.approx(w_lin, rel=10 * strain)
    print('relative force difference at strain 1e-3, 1e-4, 1e-5:', rel)
    # first order in the strain: the neo-Hookean's cubic energy terms
    assert rel[0] < 1e-2 and rel[1] / rel[2] == pytest.approx(10.0, rel=0.05)
    assert rel[0] / rel[1] == pytest.approx(10.0, rel=0.05)


def robot(**material):
    scene = read_yaml_file(CONFIG / 'shell_robot.yaml')
    for key in ('youngs_modulus_pa', 'poisson_ratio'):
        scene['material'].pop(key)
    scene['material'].update({'law': 'neo_hookean', **material})
    return scene


@pytest.mark.parametrize(
    'material, words',
    [
        ({}, 'material.law: neo_hookean needs exactly one of material.silicone'),
        ({'silicone': 'ecoflex_00_30', 'shear_modulus_pa': 1e4}, 'given both'),
        ({'shear_modulus_pa': 1e4, 'poisson_ratio': 0.3},
         "material.poisson_ratio: given with material.law 'neo_hookean', which does not use it"),
        ({'shear_modulus_pa': 1e4, 'youngs_modulus_pa': 3e4},
         "material.youngs_modulus_pa: given with material.law 'neo_hookean'"),
        ({'law': 'linear', 'youngs_modulus_pa': 3e4, 'poisson_ratio': 0.3,
          'shear_modulus_pa': 1e4},
         "material.shear_modulus_pa: given with material.law 'linear'"),
        ({'silicone': 'latex'}, "material.silicone: 'latex' is not known; allowed: one of none, "
                                'ecoflex_00_30'),
        ({'shear_modulus_pa': -5.0}, 'material.shear_modulus_pa: -5.0 is out of range'),
    ],
)
def test_scene_keys_of_the_rubber_law_are_refused_with_what_is_allowed(material, words):
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(robot(**material))
    assert words in str(err.value)


def test_a_tabled_silicone_sets_mu_and_the_small_strain_moduli():
    model = ShellModel.from_scene(robot(silicone='dragon_skin_10'))
    mu = SILICONES['dragon_skin_10'].shear_modulus_pa
    assert model.material_law == 'neo_hookean' and model.shear_modulus_pa == mu
    assert model.material['youngs_modulus_pa'] == 3 * mu
    assert model.material['poisson_ratio'] == 0.5
    assert model.flags & sk.F_NEO_HOOKEAN
    linear = ShellModel.from_scene(read_yaml_file(CONFIG / 'shell_robot.yaml'))
    assert linear.material_law == 'linear' and not linear.flags & sk.F_NEO_HOOKEAN


# ---- the balloon ----------------------------------------------------------------------------
R, H, MU = 0.05, 1e-3, 40e3 / 3  # hemisphere of 5 cm, 2 mm wall (h/R = 0.02)
P_MAX = neo_hookean_balloon_peak_pressure_pa(MU, 2 * H, R)


def hemisphere(pressure, elements):
    """Return the scene of a hemisphere whose edge is free in r and theta, held axially."""
    return {
        'model': 'shell',
        'simulation': {'dt_s': 0.05, 'integrator': 'backward_euler'},
        'geometry': {'kind': 'cap_cylinder', 'cap_radius_m': R, 'cap_opening_rad': math.pi / 2,
                     'cylinder_length_m': 0.0},
        'mesh': {'elements': elements},
        'material': {'law': 'neo_hookean', 'shear_modulus_pa': MU, 'viscosity_pa_s': 50.0,
                     'half_thickness_m': H, 'density_kg_m3': 1100.0},
        'fluid': {'density_kg_m3': 1000.0},
        # the free edge: the equator of the full balloon, whose symmetry plane holds it axially
        'jet': {'outlet': 'edge'},
        'terms': {'drag': False, 'jet': False, 'vehicle_motion': False, 'added_mass': False},
        'load': {'internal_pressure_pa': pressure},
    }


def inflate(pressure, elements, chunks=20, chunk=40):
    """Relax the hemisphere under `pressure` (backward Euler, viscous); return its stretch."""
    model = ShellModel.from_scene(hemisphere(pressure, elements))
    state = model.initial_state()
    v0 = model.ref.volume_m3()
    stretch = []
    for k in range(chunks):
        try:
            model.advance(state, k * chunk * model.dt_s, chunk, Command())
        except SimulationBlowUp:
            stretch.append(math.inf)
            break
        stretch.append((model.observe(state, 0.0, Command()).volume_m3 / v0) ** (1.0 / 3.0))
        if stretch[-1] > 2.0:
            break
    return model, state, stretch


def balloon_pressure(stretch, bending=True):
    """
    Return the neo-Hookean balloon's p = 2 mu (2h)/R (1/l - 1/l^7), plus the bending term.

    A sphere inflated uniformly in this Reissner shell also bends: d11 = d22 = (1 - l)/R, energy
    per reference area Js Psi (1 + nu) d^2 = 4 mu h^3 (l - 1)^2/R^2, which adds
    8 mu h^3 (l - 1)/(R^3 l^2) to p (relatively (h/R)^2/3 = 1.3e-4 at small stretch here).
    """
    p = spherical_balloon_pressure_pa(stretch, 0.5 * MU, 0.0, 2 * H, R)
    if bending:
        p += 8 * MU * H**3 * (stretch - 1) / (R**3 * stretch**2)
    return p


def test_hemisphere_follows_the_balloon_law_at_second_order_in_the_mesh():
    """
    Check the law's pressure at the measured stretch, (V/V0)^(1/3), at rest.

    Pressures 0.5 and 0.95 of the balloon's maximum, 16/32/64 elements: the relative error.

    Measured: -1.19e-3, -2.96e-4, -7.0e-5 (at both pressures; orders 2.0, 2.1): the mesh's
    O(ds^2) alone, once the bending term (relatively 1.3e-4) is in the law; without it the
    64-element error is -2.3e-4 to -2.9e-4.
    """
    for fraction in (0.5, 0.95):
        errors = []
        for elements in (16, 32, 64):
            _, _, stretch = inflate(fraction * P_MAX, elements)
            assert abs(stretch[-1] - stretch[-2]) < 1e-9  # at rest
            errors.append(balloon_pressure(stretch[-1]) / (fraction * P_MAX) - 1.0)
        orders = [math.log2(errors[k] / errors[k + 1]) for k in range(2)]
        print(fraction, errors, orders)
        assert min(orders) > 1.8, (errors, orders)
        assert abs(errors[-1]) < 1.5e-4
        # the pure membrane law, without the shell's bending term, within (h/R)^2 / 3 + mesh
        assert balloon_pressure(stretch[-1], bending=False) == pytest.approx(
            fraction * P_MAX, rel=5e-4)


def test_the_balloon_has_its_pressure_maximum_at_the_neo_hookean_stretch():
    """
    Check the limit point: rest just below the analytic maximum, none just above (0.5 %).

    Below, the hemisphere comes to rest below l = 7^(1/6); above, there is no rest: it inflates
    past l = 2.
    """
    _, _, below = inflate(0.995 * P_MAX, 32)
    assert 1.25 < below[-1] < NEO_HOOKEAN_BALLOON_PEAK_STRETCH
    assert abs(below[-1] - below[-2]) < 1e-9
    assert balloon_pressure(below[-1]) == pytest.approx(0.995 * P_MAX, rel=5e-4)
    _, _, above = inflate(1.005 * P_MAX, 32)
    assert above[-1] > 2.0, above


# ---- the energy ledger ----------------------------------------------------------------------
def free_mantle(dt):
    """
    Ellipsoidal mantle released from a 30 % radial perturbation; no drag, no jet.

    A little wall viscosity (20 Pa s): without any, this mantle crumples at the mesh scale within
    0.3 s under either law (the model's own diagnosis); its dissipation is booked (out_viscous).
    """
    return {
        'model': 'shell',
        'simulation': {'dt_s': dt, 'integrator': 'implicit_midpoint', 'newton_tolerance': 1e-12},
        'geometry': {'kind': 'ellipsoid', 'semi_axis_axial_m': 0.05, 'semi_axis_radial_m': 0.03,
                     'opening_radius_m': 0.01},
        'mesh': {'elements': 16},
        'material': {'law': 'neo_hookean', 'shear_modulus_pa': 40e3 / 3, 'viscosity_pa_s': 20.0,
                     'half_thickness_m': 1e-3, 'density_kg_m3': 1100.0},
        'fluid': {'density_kg_m3': 1000.0, 'added_mass_coefficient': 1.1},
        'vehicle': {'mass_kg': 0.1, 'initial_velocity_m_s': 0.2},
        'terms': {'viscosity': True, 'drag': False, 'jet': False, 'added_mass': True,
                  'vehicle_motion': True},
        'initial': {'radial_perturbation_m': 9e-3},
    }


def largest_closure(scene, duration, samples=50):
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    n = int(round(duration / samples / model.dt_s))
    worst, hoop = 0.0, 1.0
    for k in range(samples):
        model.advance(state, k * n * model.dt_s, n, Command())
        worst = max(worst, abs(model.energy_ledger(state)['closure_relative']))
        r, _ = model.profile(state)
        hoop = max(hoop, float(np.max(r[1:] / model.ref.r0[1:])))
    return worst, hoop


def test_ledger_closes_at_second_order_in_a_large_free_oscillation():
    """
    Implicit midpoint: the closure error falls four-fold per halved step; hoop stretch to 1.27.

    Measured: 1.45e-4, 3.64e-5 (ratio 3.99).
    """
    (e1, hoop), (e2, _) = (largest_closure(free_mantle(dt), 0.3) for dt in (4e-4, 2e-4))
    print('largest hoop stretch', hoop, 'closure', e1, e2, 'ratio', e1 / e2)
    assert hoop > 1.25  # the nonlinear range of the law
    assert e1 < 5e-4 and e1 / e2 == pytest.approx(4.0, rel=0.15)


@pytest.mark.parametrize('name', ['shell_robot', 'shell_cone'])
def test_ledger_closes_at_second_order_with_cable_and_muscle(name):
    """
    Check the ledger of the shipped robot (cable) and cone (muscle: the active strain's power).

    The wall made neo-Hookean at mu = E/3; 2 s, converged Newton solves. Measured ratios 4.0
    and 4.0.
    """
    closures = []
    for halving in (1, 2):
        scene = read_yaml_file(CONFIG / f'{name}.yaml')
        young = scene['material'].pop('youngs_modulus_pa')
        scene['material'].pop('poisson_ratio')
        scene['material'].update(law='neo_hookean', shear_modulus_pa=young / 3)
        scene['simulation'] = {**scene['simulation'], 'newton_tolerance': 1e-11,
                               'dt_s': scene['simulation']['dt_s'] / halving}
        model = ShellModel.from_scene(copy.deepcopy(scene))
        state = model.initial_state()
        model.advance(state, 0.0, int(round(2.0 / model.dt_s)), Command())
        led = model.energy_ledger(state)
        assert led['in_actuation_work'] > 0 and led['out_viscous'] > 0
        closures.append(led['closure_relative'])
    print(name, closures)
    assert abs(closures[0]) < 1e-4
    assert closures[0] / closures[1] == pytest.approx(4.0, rel=0.1)
