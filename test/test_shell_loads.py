"""
Shell model: distributed loads enter as their work-equivalent (consistent) nodal loads.

The nodal loads reproduce the continuous load's total and first moment at any mesh, and a smooth
cable-loaded shell converges at second order in the mesh (issue 23: lumping the held ends' shares
onto the free nodes made it first order).
"""

import math
import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.model import (
    consistent_area_shares, consistent_line_load, ShellModel
)
import pytest
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
ELLIPSOID = {
    'kind': 'ellipsoid',
    'semi_axis_axial_m': 0.05,
    'semi_axis_radial_m': 0.03,
    'opening_radius_m': 0.01,
}
CAP_CYLINDER = {
    'kind': 'cap_cylinder',
    'cap_radius_m': 0.031,
    'cap_opening_rad': 0.7853981634,
    'cylinder_length_m': 0.151,
}


def scene(geometry, elements, distribution, outlet='ring', coupling='consistent'):
    jet = {'outlet': outlet} if outlet == 'edge' else {'outlet': outlet, 'outlet_radius_m': 0.005}
    return {
        'model': 'shell',
        'coupling': coupling,
        'simulation': {'dt_s': 0.05, 'integrator': 'backward_euler'},
        'geometry': geometry,
        'mesh': {'elements': elements},
        'material': {
            'youngs_modulus_pa': 4e4,
            'viscosity_pa_s': 50.0,
            'poisson_ratio': 0.0,
            'half_thickness_m': 1e-3,
            'density_kg_m3': 1100.0,
        },
        'fluid': {'density_kg_m3': 1000.0},
        'jet': jet,
        'terms': {'drag': False, 'jet': False, 'vehicle_motion': False, 'added_mass': False},
        'actuation': {'kind': 'cable', 'source': 'command', 'distribution': distribution},
    }


def continuous(distribution, a, b, length):
    """Total and first moment of the density (uniform 1, rising X/L, falling 1 - X/L) on [a, b]."""
    if distribution == 'uniform':
        return b - a, (b * b - a * a) / 2
    if distribution == 'rising':
        return (b * b - a * a) / (2 * length), (b ** 3 - a ** 3) / (3 * length)
    return (
        (b - a) - (b * b - a * a) / (2 * length),
        (b * b - a * a) / 2 - (b ** 3 - a ** 3) / (3 * length),
    )


@pytest.mark.parametrize('distribution', ['uniform', 'rising', 'falling'])
@pytest.mark.parametrize('elements', [4, 7, 20, 101, 400])
def test_line_load_shares_have_the_continuous_total_and_first_moment(distribution, elements):
    X = np.linspace(0.0, 0.16, elements + 1)
    xi = X / X[-1]
    f = {'uniform': np.ones_like(X), 'rising': xi, 'falling': 1 - xi}[distribution]
    for start in (0, 3):
        w = consistent_line_load(X, f, start)
        total, moment = continuous(distribution, X[start], X[-1], X[-1])
        assert w.sum() == pytest.approx(1.0, rel=1e-13)
        assert np.dot(w, X) == pytest.approx(moment / total, rel=1e-13)
        assert not np.any(w[:start])


@pytest.mark.parametrize('elements', [5, 24, 100])
def test_area_shares_have_the_surface_total_and_first_moment(elements):
    X = np.linspace(0.0, 0.1, elements + 1)
    r = 0.01 + 0.02 * X / X[-1]  # a cone: straight meridian, ds = dX
    w = consistent_area_shares(r, np.diff(X), 2)
    a, b = X[2], X[-1]
    # dA = 2 pi r dX, r = r_a + k (X - ...): integrate r and X r exactly
    k = 0.02 / X[-1]
    total = 0.01 * (b - a) + k * (b * b - a * a) / 2
    moment = 0.01 * (b * b - a * a) / 2 + k * (b ** 3 - a ** 3) / 3
    assert w.sum() == pytest.approx(1.0, rel=1e-13)
    assert np.dot(w, X) == pytest.approx(moment / total, rel=1e-13)
    assert not np.any(w[:2])


@pytest.mark.parametrize('distribution', ['uniform', 'rising', 'falling'])
@pytest.mark.parametrize('outlet', ['ring', 'edge'])
@pytest.mark.parametrize('elements', [8, 30, 100])
def test_the_cable_applies_the_consistent_shares_and_the_supports_take_the_rest(
    distribution, outlet, elements
):
    model = ShellModel.from_scene(scene(CAP_CYLINDER, elements, distribution, outlet))
    X = model.ref.X
    w = model.Nd[:, sk.N_WC]
    total, moment = continuous(distribution, 0.0, X[-1], X[-1])
    h = X[1] - X[0]
    xi = X / X[-1]
    f = {'uniform': np.ones_like(X), 'rising': xi, 'falling': 1 - xi}[distribution] / total
    # the held ends' shares: the pole (r held) and, when clamped, the ring
    pole = h * (2 * f[0] + f[1]) / 6
    ring = h * (f[-2] + 2 * f[-1]) / 6
    held = pole + (ring if outlet == 'ring' else 0.0)
    assert w[0] == 0.0 and (w[-1] == 0.0) == (outlet == 'ring')
    assert w.sum() == pytest.approx(1.0 - held, rel=1e-12)
    # with the supports' shares put back, the total and first moment of the continuous load
    full = w.copy()
    full[0] += pole
    if outlet == 'ring':
        full[-1] += ring
    assert full.sum() == pytest.approx(1.0, rel=1e-12)
    assert np.dot(full, X) == pytest.approx(moment / total, rel=1e-12)
    if distribution == 'uniform':
        # interior nodes: ds/L = 1/N each (not 1/(N - 1) as a share of the free nodes)
        assert np.allclose(w[1:-1], 1.0 / elements, rtol=1e-12)
        if outlet == 'edge':
            assert w[-1] == pytest.approx(0.5 / elements, rel=1e-12)


def test_paper_code_wall_load_uses_the_wall_only():
    s = scene(CAP_CYLINDER, 40, 'uniform', 'free_edge_fixed_nozzle', 'paper_code')
    s['jet'] = {'outlet': 'free_edge_fixed_nozzle', 'outlet_radius_m': 0.0125}
    model = ShellModel.from_scene(s)
    k = model.code_rim
    ww = model.Nd[:, sk.N_WWALL]
    assert not np.any(ww[:k]) and ww.sum() == pytest.approx(1.0, rel=1e-13)
    # the rim node's share is half its wall element's, not half the cap's element as well
    r0, ds = model.ref.r0, model.E[:, sk.E_DS]
    area_wall = float(np.sum(model.E[k:, sk.E_AREA])) / (2 * math.pi)
    assert ww[k] == pytest.approx(ds[k] * (2 * r0[k] + r0[k + 1]) / 6 / area_wall, rel=1e-12)
    # the cable is a load along the deformable wall only: its shares start at the rim
    w = model.Nd[:, sk.N_WC]
    assert not np.any(w[: k + 1])


def static_cable(elements, distribution, force_n=0.5):
    model = ShellModel.from_scene(scene(ELLIPSOID, elements, distribution))
    state = model.initial_state()
    model.advance(state, 0.0, 200, Command(cable_force_n=force_n))
    return model.observe(state, 10.0, Command()).volume_m3 - model.ref.volume_m3()


@pytest.mark.parametrize('distribution', ['uniform', 'falling'])
def test_static_cable_load_converges_at_second_order_in_mesh_size(distribution):
    """A smooth shell (ellipsoid) pulled by the cable to equilibrium: observed order >= 1.8."""
    dv = [static_cable(n, distribution) for n in (8, 16, 32, 64)]
    diffs = [abs(dv[k + 1] - dv[k]) for k in range(3)]
    orders = [math.log2(diffs[k] / diffs[k + 1]) for k in range(2)]
    # measured 1.91-1.96 (8/16/32/64 elements); with the free nodes' shares 1/(N-1) of the
    # previous lumping: 0.83-0.94
    assert min(orders) >= 1.8, orders


# a cone from a sharp apex (slant 0.05 m) and a cylinder (0.05 m): a kink of the wall's normal
# half way along the meridian, straight on either side, so the continuous wall loads of a uniform
# velocity have closed forms and every even mesh puts a node on the kink
CONE_CYLINDER = {'kind': 'points', 'points': [[0.0, 0.09], [0.03, 0.05], [0.03, 0.0]]}
SIDES = (  # (area, tangent from the pole, outward normal) of the cone and the cylinder
    (math.pi * 0.03 * 0.05, np.array([0.6, -0.8]), np.array([0.8, 0.6])),
    (2 * math.pi * 0.03 * 0.05, np.array([0.0, -1.0]), np.array([1.0, 0.0])),
)
VELOCITIES = ([0.0, 0.3], [0.2, -0.1], [-0.25, 0.4])


def loaded_scene(geometry, elements):
    s = scene(geometry, elements, 'uniform')
    s['terms'] = {'drag': True, 'jet': False, 'vehicle_motion': False, 'added_mass': True}
    return s


def polygon_sides(model):
    """(area, tangent, normal) of each element of the reference meridian through the nodes."""
    r0, z0 = model.ref.r0, model.ref.z0
    out = []
    for e in range(r0.size - 1):
        d = np.array([r0[e + 1] - r0[e], z0[e + 1] - z0[e]])
        t = d / np.hypot(*d)
        out.append((math.pi * (r0[e] + r0[e + 1]) * np.hypot(*d), t, np.array([-t[1], t[0]])))
    return out


@pytest.mark.parametrize('elements', [4, 7, 20, 101])
def test_added_mass_blocks_have_the_continuous_kinetic_energy_of_a_uniform_velocity(elements):
    """
    Element by element, the nodal added-mass blocks hold the water's kinetic energy exactly.

    1/2 sum_i v^T B_i v = 1/2 int C_a rho l_a (n . v)^2 dA of a uniform velocity v, on the
    meridian through the nodes at any mesh and on the cone/cylinder itself when a node sits on
    its kink (even meshes): each side keeps its own normal.
    """
    model = ShellModel.from_scene(loaded_scene(CONE_CYLINDER, elements))
    per_area = 1.1 * 1000.0 * 0.5 * 0.03  # C_a rho l_a, l_a half the largest radius
    B = model.am_blocks
    m = model.node_mass
    assert np.allclose(model.Nd[:, sk.N_MRR], m + B[:, 0], rtol=1e-15, atol=0)
    assert np.allclose(model.Nd[:, sk.N_MZZ], m + B[:, 2], rtol=1e-15, atol=0)
    assert np.array_equal(model.Nd[:, sk.N_MRZ], B[:, 1])
    assert B.sum(axis=0)[[0, 2]].sum() == pytest.approx(model.node_added_mass.sum(), rel=1e-13)
    for v in map(np.array, VELOCITIES):
        nodal = 0.5 * np.sum(B[:, 0] * v[0] ** 2 + 2 * B[:, 1] * v[0] * v[1] + B[:, 2] * v[1] ** 2)
        sides = polygon_sides(model) if elements % 2 else SIDES
        exact = 0.5 * per_area * sum(a * np.dot(n, v) ** 2 for a, _, n in sides)
        assert nodal == pytest.approx(exact, rel=1e-12)
    if elements % 2 == 0:
        k = elements // 2
        half = [0.5 * per_area * model.E[e, sk.E_AREA] for e in (k - 1, k)]
        block = sum(h * np.outer(n, n) for h, (_, _, n) in zip(half, SIDES))
        assert np.allclose(B[k], block[[0, 0, 1], [0, 1, 1]], rtol=1e-12, atol=0)


def drag_forces(model, q, v, U=0.0):
    """Return the generalised forces of the tangential drag alone at (q, v), and its power."""
    n = q.size
    out = []
    for flags in (sk.F_DRAG, 0):  # the elements' forces are in both
        F, gV, vrel, st = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(sk.N_STATS)
        sk.forces(flags, q, v, U, 0.0, 0.0, model.E, model.Nd, model.P, F, gV, vrel, st)
        out.append((F, vrel, st[sk.T_PDRAG]))
    return out[0][0] - out[1][0], out[0][1], out[0][2]


def reference_state(model):
    n1 = model.n_nodes
    q = np.zeros(3 * n1)
    q[0::3], q[1::3], q[2::3] = model.ref.r0, model.ref.z0, model.ref.theta0
    return q


@pytest.mark.parametrize('elements', [4, 7, 20, 101])
def test_tangential_drag_has_the_continuous_total_of_a_uniform_velocity(elements):
    """
    The element halves' drag sums to the continuous drag of a uniform velocity.

    -1/2 rho C_t int |v . t| (v . t) t dA over the meridian through the nodes at any mesh, and
    over the cone/cylinder itself when a node sits on its kink. The vehicle moves at v_z, so the
    clamped ring moves axially with it and the pole (held radially) moves axially only: their
    halves see those velocities; the radial shares of both go to the supports, the ring's axial
    share to the ring's reaction (the vehicle).
    """
    model = ShellModel.from_scene(loaded_scene(CONE_CYLINDER, elements))
    cdr = 0.5 * 1000.0 * 0.05
    n1 = model.n_nodes
    q = reference_state(model)
    sides = polygon_sides(model)

    def half(a, t, w):
        return -cdr * 0.5 * a * abs(np.dot(w, t)) * np.dot(w, t) * t

    for v in map(np.array, VELOCITIES):
        vel = np.zeros(3 * n1)
        vel[0::3], vel[1::3] = v[0], v[1]
        F, _, pdrag = drag_forces(model, q, vel, U=v[1])
        axial = np.array([0.0, v[1]])
        pole = half(*sides[0][:2], axial)
        ring = half(*sides[-1][:2], axial)
        total = np.array([F[0::3].sum() + pole[0] + ring[0], F[1::3].sum()])
        exact = sum(2 * half(a, t, v) for a, t, _ in (sides if elements % 2 else SIDES))
        exact += pole + ring - half(*sides[0][:2], v) - half(*sides[-1][:2], v)
        assert total == pytest.approx(exact, rel=1e-12, abs=1e-15)
        assert F[3 * n1 - 2] == pytest.approx(ring[1], rel=1e-12)  # on the ring: the vehicle's
        # the power booked is the forces' work on the nodes' velocities
        w = vel.copy()
        w[0] = w[3 * n1 - 3] = 0.0
        assert pdrag == pytest.approx(-np.dot(F, w), rel=1e-12)
    if elements % 2 == 0:
        # the kink node: each side's half along its own side
        k = elements // 2
        v = np.array(VELOCITIES[1])
        vel = np.zeros(3 * n1)
        vel[0::3], vel[1::3] = v[0], v[1]
        F, _, _ = drag_forces(model, q, vel, U=v[1])
        want = sum(half(model.E[e, sk.E_AREA], t, v) for e, (_, t, _) in zip((k - 1, k), SIDES))
        assert F[3 * k:3 * k + 2] == pytest.approx(want, rel=1e-12)


def test_tangential_drag_jacobian_matches_finite_differences():
    """assemble_KC's drag terms: dF/dv, and dF/dq through the elements' current chords."""
    model = ShellModel.from_scene(loaded_scene(CONE_CYLINDER, 10))
    n = 3 * model.n_nodes
    rng = np.random.default_rng(3)
    q = reference_state(model) + 2e-3 * rng.standard_normal(n)
    v = 0.3 * rng.standard_normal(n)
    U = 0.05
    free = np.array([not sk.fixed_dof(model.Nd, k) for k in range(n)])
    q[~free] = reference_state(model)[~free]

    def dense(band):
        out = np.zeros((n, n))
        for i in range(n):
            for j in range(max(0, i - sk.BW), min(n, i + sk.BW + 1)):
                out[i, j] = band[i, j - i + sk.BW]
        return out

    def jac(flags):
        vrel = drag_forces(model, q, v, U)[1]
        K = np.zeros((n, 2 * sk.BW + 1))
        C = np.zeros((n, 2 * sk.BW + 1))
        sk.assemble_KC(flags, q, vrel, U, 0.0, model.E, model.Nd, model.P, K, C)
        return dense(K), dense(C)

    K1, C1 = jac(sk.F_DRAG)
    K0, C0 = jac(0)
    Kd, Cd = K1 - K0, C1 - C0  # the drag's own terms (the element forces' are in both)
    Kf, Cf = np.zeros((n, n)), np.zeros((n, n))
    for j in range(n):
        for x, M in ((q, Kf), (v, Cf)):
            h = 1e-6 * (1.0 + abs(x[j]))
            xs = x[j]
            x[j] = xs + h
            Fp = drag_forces(model, q, v, U)[0]
            x[j] = xs - h
            Fm = drag_forces(model, q, v, U)[0]
            x[j] = xs
            M[:, j] = (Fp - Fm) / (2 * h)
    rows = free
    assert np.abs(Kf[rows]).max() > 0 and np.abs(Cf[rows]).max() > 0
    assert np.allclose(Kd[rows], Kf[rows], rtol=0, atol=1e-6 * np.abs(Kf[rows]).max())
    # C on the free columns: a held dof's velocity column is cut from the Newton matrix
    sub = np.ix_(free, free)
    assert np.allclose(Cd[sub], Cf[sub], rtol=0, atol=1e-6 * np.abs(Cf[sub]).max())


def cone_speed(elements, duration_s=0.3):
    """Return the speed of the cone scene (smooth: rounded apex, straight wall) from rest."""
    s = yaml.safe_load((CONFIG / 'shell_cone.yaml').read_text())
    s['mesh']['elements'] = elements
    s['simulation']['newton_tolerance'] = 1e-10
    model = ShellModel.from_scene(s)
    state = model.initial_state()
    model.advance(state, 0.0, int(round(duration_s / model.dt_s)), Command())
    return model.observe(state, duration_s, Command()).velocity_m_s


def test_smooth_shell_speed_converges_at_second_order_in_mesh_size():
    """
    The vehicle speed of a smooth mantle with every wall load on: observed order >= 1.8.

    The tangential drag and the added mass act element by element and the held ring's element
    half takes its share (its drag through the ring's reaction, its axial added mass with the
    vehicle): measured 1.94 and 2.25 (32/64/128/256 elements, 0.3 s); with the nodal loads and
    the ring's half left out 1.67 and 1.61.
    """
    u = [cone_speed(n) for n in (32, 64, 128, 256)]
    diffs = [u[k + 1] - u[k] for k in range(3)]
    assert diffs[0] * diffs[1] > 0 and diffs[1] * diffs[2] > 0, u
    orders = [math.log2(diffs[k] / diffs[k + 1]) for k in range(2)]
    assert min(orders) >= 1.8, orders
