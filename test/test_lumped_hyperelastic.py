"""
The lumped model's rubber shell (material.law neo_hookean / mooney_rivlin).

Each test states what it checks and prints the figure: the membrane's strain energy against the
spherical balloon's closed-form inflation law and its pressure maximum, its force and stiffness
against its own energy, the ledger's closure at RK4's order, the small oscillation at the
membrane's tangent stiffness, and the scene keys' errors. Theory: docs/theory/hyperelastic.md.
"""

import copy
import math

import numpy as np
from pulsejet_sim.core.model_io import Command, SimulationBlowUp
from pulsejet_sim.engine.simulation import Simulation
from pulsejet_sim.models.lumped import batch
from pulsejet_sim.models.lumped import kernels as K
from pulsejet_sim.models.rubber import (
    neo_hookean_balloon_peak_pressure_pa,
    NEO_HOOKEAN_BALLOON_PEAK_STRETCH,
    SILICONES,
    spherical_balloon_pressure_pa,
)
from pulsejet_sim.scene import SceneError
from pulsejet_sim.scene.loader import load_scene_data, scene_from_dict
import pytest
from scipy import integrate, optimize

R0, H0 = 0.05, 1.0e-3  # a balloon of 10 cm, 1 mm of rubber


def balloon_pressure_from_kernel(stretch, c1, c2):
    """Return p = dU/dlambda / dV/dlambda of a sphere inflated uniformly (kernel's partials)."""
    _, du_da, du_db, _ = K.membrane_spheroid(R0, R0, stretch * R0, stretch * R0, c1, c2, H0)
    return R0 * (du_da + du_db) / (4.0 * math.pi * R0**3 * stretch**2)


@pytest.mark.parametrize('c1,c2', [(20e3, 0.0), (20e3, 4e3)])
def test_sphere_reproduces_the_balloon_inflation_law(c1, c2):
    """Neo-Hookean p = 2 mu H0/R0 (1/l - 1/l^7); Mooney-Rivlin adds 4 C2 H0/R0 (l - 1/l^5)."""
    stretches = np.linspace(1.001, 6.0, 400)
    errors = [
        abs(
            balloon_pressure_from_kernel(s, c1, c2)
            / spherical_balloon_pressure_pa(s, c1, c2, H0, R0)
            - 1.0
        )
        for s in stretches
    ]
    print(f'C1 {c1:g} Pa, C2 {c2:g} Pa: largest relative error {max(errors):.2e} over 1 < l <= 6')
    # a uniform stretch makes the integrand a constant times sin(theta): the quadrature is exact
    # to round-off, so the tolerance is round-off's
    assert max(errors) < 1e-12


def test_neo_hookean_balloon_pressure_maximum_at_seventh_root():
    """The kernel's balloon pressure peaks at lambda = 7^(1/6) = 1.3831 with 2 mu H0/R0 0.6198."""
    mu = 40e3
    best = optimize.minimize_scalar(
        lambda s: -balloon_pressure_from_kernel(s, 0.5 * mu, 0.0),
        bounds=(1.1, 2.0),
        method='bounded',
        options={'xatol': 1e-10},
    )
    peak = -best.fun
    expected = neo_hookean_balloon_peak_pressure_pa(mu, H0, R0)
    print(
        f'peak at lambda {best.x:.8f} (7^(1/6) = {NEO_HOOKEAN_BALLOON_PEAK_STRETCH:.8f}), '
        f'{peak:.6f} Pa vs {expected:.6f} Pa'
    )
    assert best.x == pytest.approx(NEO_HOOKEAN_BALLOON_PEAK_STRETCH, abs=1e-5)
    assert peak == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(2 * mu * H0 / R0 * 7 ** (-1 / 6) * 6 / 7, rel=1e-14)


def independent_energy(a, b0, b, c1, c2, thickness):
    """Return the membrane energy by adaptive quadrature (scipy), from the docs' formulas."""

    def density(theta):
        s, c = math.sin(theta), math.cos(theta)
        s0 = math.hypot(a * s, b0 * c)
        h, m = b / b0, math.hypot(a * s, b * c) / s0
        i1 = h * h + m * m + 1 / (h * m) ** 2
        i2 = 1 / h**2 + 1 / m**2 + (h * m) ** 2
        return 2 * math.pi * b0 * s * s0 * (c1 * (i1 - 3) + c2 * (i2 - 3))

    value, _ = integrate.quad(density, 0.0, math.pi / 2, epsabs=0.0, epsrel=1e-12, limit=200)
    return 2 * thickness * value


@pytest.mark.parametrize('ratio', [0.34, 0.7, 1.001, 2.0, 3.8, 4.9])
def test_lumped_membrane_force_and_stiffness_are_its_energy_derivatives(ratio):
    """On the escape robot's ellipsoid (a = 0.15, b0 = 0.03): U, dU/db, d2U/db2 at b = ratio b0."""
    a, b0, c1, c2, t = 0.15, 0.03, 19.7e3, 2e3, 1.5e-3
    b = ratio * b0
    energy, _, force, stiffness = K.membrane_spheroid(a, b0, a, b, c1, c2, t)
    reference = independent_energy(a, b0, b, c1, c2, t)
    step = 1e-6 * b
    up = K.membrane_spheroid(a, b0, a, b + step, c1, c2, t)
    down = K.membrane_spheroid(a, b0, a, b - step, c1, c2, t)
    fd_force = (up[0] - down[0]) / (2 * step)
    fd_stiffness = (up[2] - down[2]) / (2 * step)
    print(
        f'b/b0 {ratio}: U {energy:.6e} J (adaptive {reference:.6e}), dU/db {force:.6e} N '
        f'(central difference {fd_force:.6e}), d2U/db2 {stiffness:.6e} N/m ({fd_stiffness:.6e})'
    )
    # the quadrature's error (24 Gauss-Legendre nodes): the squeezed membrane's energy gathers at
    # the poles, where 24 nodes resolve it less well
    assert energy == pytest.approx(reference, rel=1e-8 if ratio < 0.5 else 1e-11)
    assert force == pytest.approx(fd_force, rel=1e-7, abs=1e-9)
    assert stiffness == pytest.approx(fd_stiffness, rel=1e-7)


def rubber_scene(material=None, **sections):
    """Build the escape robot as measured, its hull a rubber membrane (Ecoflex 00-30 default)."""
    data, _ = load_scene_data('escape_weymouth2015')
    data = copy.deepcopy(data)
    data['material'].pop('stiffness_n_m')
    data['material'].update(material or {'law': 'neo_hookean', 'silicone': 'ecoflex_00_30'})
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
    return scene_from_dict(data, 'rubber')


def test_ledger_closes_at_the_integrator_order_with_the_rubber_shell():
    """The stored elastic energy is the membrane's U(b): the books close at RK4's 4th order."""
    errors = []
    for dt in (8e-4, 4e-4, 2e-4):
        model = rubber_scene(simulation={'dt_s': dt}).model
        y = model.initial_state()
        model.advance(y, 0.0, int(round(2.0 / dt)), Command(0.0, 1.0, 0.0))
        ledger = model.energy_ledger(y)
        errors.append(abs(ledger['closure_error']))
    e0 = ledger['in_initial']
    orders = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    print(f'in_initial {e0:.4f} J; closure {errors} J at dt 8e-4, 4e-4, 2e-4 s; orders {orders}')
    c1 = SILICONES['ecoflex_00_30'].shear_modulus_pa / 2
    assert e0 == pytest.approx(
        K.membrane_spheroid(0.15, 0.03, 0.15, 0.114, c1, 0.0, 0.0015)[0], rel=1e-12
    )
    assert errors[-1] < 1e-9 * e0
    assert all(order > 3.5 for order in orders)


def test_small_oscillation_period_follows_the_membrane_tangent_stiffness():
    """Released at 1.001 b0, the shell rings at 2 pi sqrt(m_eff / (d2U/db2 at b0))."""
    scene = rubber_scene(geometry={'initial_minor_semi_axis_m': 0.03 * 1.001})
    sim = Simulation(scene.model)
    model = sim.model
    times, widths = [], []
    while sim.time_s < 3.0 - 1e-12:
        obs = sim.step(10)
        times.append(obs.time_s)
        widths.append(obs.mantle_radius_m - 0.03)
    d = model.diagnostics(model.initial_state(), sim.command)
    c1 = model.params[K.P_MR_C1]
    stiffness = K.membrane_spheroid(0.15, 0.03, 0.15, 0.03, c1, 0.0, 0.0015)[3]
    expected = 2 * math.pi * math.sqrt(d[K.D_B_MASS] / stiffness)
    down = [
        times[i] - widths[i] * (times[i + 1] - times[i]) / (widths[i + 1] - widths[i])
        for i in range(len(widths) - 1)
        if widths[i] > 0 >= widths[i + 1]
    ]
    measured = float(np.mean(np.diff(down)))
    print(f'period {measured:.5f} s, 2 pi sqrt(m/k_t) {expected:.5f} s (k_t {stiffness:.1f} N/m)')
    assert model.params[K.P_K] == pytest.approx(stiffness, rel=1e-14)
    assert len(down) >= 4
    assert measured == pytest.approx(expected, rel=2e-3)


def test_pump_relief_defaults_use_the_membrane_pressure():
    """The pump's relief and stall pressures default to dU/db / V_b at b = 0.8 a and 0.9 a."""
    model = rubber_scene().model
    p = model.params
    for b, key in ((0.8 * 0.15, K.P_P_RELIEF), (0.9 * 0.15, K.P_P_STALL)):
        force = K.membrane_spheroid(0.15, 0.03, 0.15, b, p[K.P_MR_C1], 0.0, 0.0015)[2]
        assert p[key] == pytest.approx(force / (8 / 3 * math.pi * 0.15 * b), rel=1e-14)


def test_membrane_pressure_rises_monotonically_for_every_tabled_silicone():
    """At fixed length the membrane's pressure has no maximum up to b = a (unlike a balloon's)."""
    a, b0 = 0.15, 0.03
    widths = np.linspace(1.001 * b0, 0.999 * a, 300)
    for name, silicone in SILICONES.items():
        pressures = [
            K.membrane_spheroid(a, b0, a, b, silicone.shear_modulus_pa / 2, 0.0, 0.0015)[2]
            / (8 / 3 * math.pi * a * b)
            for b in widths
        ]
        print(f'{name}: mu {silicone.shear_modulus_pa:.0f} Pa, p(b = a) {pressures[-1]:.0f} Pa')
        assert np.all(np.diff(pressures) > 0), name


def test_an_unbounded_membrane_blow_up_says_so():
    """A hull too stiff for the model's bounds stops with SimulationBlowUp naming the bound."""
    scene = rubber_scene({'law': 'neo_hookean', 'shear_modulus_pa': 1e9})
    sim = Simulation(scene.model)
    with pytest.raises(SimulationBlowUp, match='speed|collapsed|sub-steps') as err:
        for _ in range(2000):
            sim.step(10)
    print(err.value)


def test_batch_kernel_refuses_the_rubber_shell():
    """The vectorised batch has only the linear spring: it says so instead of running it."""
    with pytest.raises(ValueError, match='material.law'):
        batch.batch_kernel(rubber_scene().model.flags)


@pytest.mark.parametrize(
    'material,words',
    [
        ({'law': 'neo_hookean', 'silicone': 'ecoflex_00_30', 'stiffness_n_m': 2094},
         ['material.stiffness_n_m', 'neo_hookean', 'allowed']),
        ({'law': 'neo_hookean'}, ['material.law', 'exactly one', 'neither']),
        ({'law': 'neo_hookean', 'silicone': 'ecoflex_00_30', 'shear_modulus_pa': 3e4},
         ['material.law', 'both']),
        ({'law': 'neo_hookean', 'silicone': 'sylgard'}, ['material.silicone', 'ecoflex_00_30']),
        ({'law': 'neo_hookean', 'shear_modulus_pa': 0}, ['material.shear_modulus_pa', 'range']),
        ({'law': 'mooney_rivlin', 'mooney_rivlin_c2_pa': 1e3},
         ['material.mooney_rivlin_c1_pa', 'missing']),
        ({'law': 'mooney_rivlin', 'mooney_rivlin_c1_pa': 1e4, 'silicone': 'dragon_skin_10'},
         ['material.silicone', 'mooney_rivlin']),
        ({'law': 'rubber'}, ['material.law', 'neo_hookean']),
    ],
)
def test_material_keys_are_checked_for_their_law(material, words):
    """Each bad combination is refused with the key, the value and what is allowed."""
    with pytest.raises(SceneError) as err:
        rubber_scene(material)
    print(err.value)
    for word in words:
        assert word in str(err.value)


def test_linear_law_key_is_the_default_and_refuses_rubber_keys():
    """law: linear given or not builds the same model; a rubber key with it is refused."""
    data, _ = load_scene_data('escape_weymouth2015')
    plain = scene_from_dict(copy.deepcopy(data), 'plain').model
    data = copy.deepcopy(data)
    data['material']['law'] = 'linear'
    explicit = scene_from_dict(copy.deepcopy(data), 'explicit').model
    assert np.array_equal(plain.params, explicit.params) and plain.flags == explicit.flags
    assert not plain.flags & K.O_HYPERELASTIC and plain.shell_law == 'linear'
    data['material']['shear_modulus_pa'] = 3e4
    with pytest.raises(SceneError, match='material.shear_modulus_pa'):
        scene_from_dict(data, 'bad')


def test_mooney_rivlin_scene_builds_and_closes_its_books():
    """law: mooney_rivlin takes C1 and C2 as given; the energy at t = 0 is the membrane's."""
    scene = rubber_scene(
        {'law': 'mooney_rivlin', 'mooney_rivlin_c1_pa': 15e3, 'mooney_rivlin_c2_pa': 3e3}
    )
    model = scene.model
    assert model.shell_law == 'mooney_rivlin' and model.flags & K.O_HYPERELASTIC
    assert (model.params[K.P_MR_C1], model.params[K.P_MR_C2]) == (15e3, 3e3)
    y = model.initial_state()
    model.advance(y, 0.0, 5000, Command(0.0, 1.0, 0.0))
    ledger = model.energy_ledger(y)
    expected = K.membrane_spheroid(0.15, 0.03, 0.15, 0.114, 15e3, 3e3, 0.0015)[0]
    print(f"in_initial {ledger['in_initial']:.6f} J, closure {ledger['closure_error']:.2e} J")
    assert ledger['in_initial'] == pytest.approx(expected, rel=1e-12)
    assert abs(ledger['closure_relative']) < 1e-10
