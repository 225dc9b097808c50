"""
The water inside the mantle as a one-dimensional flow (experiment I, docs/theory/shell.md).

``fluid.internal_inertia: one_dimensional`` gives the water inside the kinetic energy
``1/2 rho Lambda V'^2`` of paper 001's section 3.4 flow: its inertance against geometry, its
energy against the ledger, the mode it creates against a one-mode estimate, and its refusals.
"""

import math
import re

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError, SimulationBlowUp
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.geometry import build_reference_meridian
from pulsejet_sim.models.shell.model import ShellModel
import pytest
from scipy.integrate import quad
from test_shell_coupling import cone_scene, run


def test_inertance_of_a_closed_cylinder_is_its_length_over_three_sections():
    """A cylinder closed at one end: the flux grows linearly, Lambda = L / (3 pi R^2)."""
    length, radius = 0.12, 0.02
    profile = build_reference_meridian(
        {'kind': 'points', 'points': [[0.0, length], [radius, length], [radius, 0.0]]}, 4000
    )
    expected = length / (3.0 * math.pi * radius**2)
    assert profile.internal_inertance_per_m() == pytest.approx(expected, rel=1e-4)


def test_inertance_of_the_ellipsoid_is_paper_001s_internal_flow():
    """
    Paper 001 section 3.4: F(x) = (2 pi/3) a b b' (1 + x)^2 (2 - x), A = pi b^2 (1 - x^2).

    The kinetic energy 1/2 rho a int F^2/A dx up to the open end x_e, over 1/2 rho F(x_e)^2.
    """
    a, b, r_open = 0.08, 0.03, 0.0125
    x_e = math.sqrt(1.0 - (r_open / b) ** 2)

    def flux(x):
        return (1.0 + x) ** 2 * (2.0 - x)

    integral, _ = quad(lambda x: flux(x) ** 2 / (math.pi * b * b * (1.0 - x * x)), -1.0, x_e)
    expected = a * integral / flux(x_e) ** 2
    profile = build_reference_meridian(
        {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': a,
            'semi_axis_radial_m': b,
            'opening_radius_m': r_open,
        },
        4000,
    )
    assert profile.internal_inertance_per_m() == pytest.approx(expected, rel=1e-4)


def test_inertance_of_the_current_shape_and_its_gradient():
    """shell.kernels.inertance: the reference mesh's Lambda, and an exact gradient."""
    scene = cone_scene('paper', 1e-3)
    scene['fluid']['internal_inertia'] = 'one_dimensional_deforming'
    model = ShellModel.from_scene(scene)
    n1 = model.n_nodes
    rest = model.initial_state()[: 3 * n1].copy()
    assert sk.inertance(rest, n1, np.zeros(3 * n1)) == pytest.approx(
        model.ref.internal_inertance_per_m(), rel=1e-12
    )
    q = run(model, 0.3)[: 3 * n1].copy()  # the rising pull narrows the edge
    grad = np.zeros(3 * n1)
    lam = sk.inertance(q, n1, grad)
    assert lam > 1.5 * model.P[sk.P_LAMBDA]
    assert model.inertance(run(model, 0.3)) == pytest.approx(lam, rel=1e-12)
    for k in range(3 * n1):
        step = np.zeros(3 * n1)
        step[k] = 1e-7
        central = (
            sk.inertance(q + step, n1, np.zeros(3 * n1))
            - sk.inertance(q - step, n1, np.zeros(3 * n1))
        ) / 2e-7
        assert central == pytest.approx(grad[k], abs=1e-7 * np.abs(grad).max()), k


@pytest.mark.parametrize(
    'fluid',
    [
        {'internal_inertia': 'one_dimensional'},
        {'internal_inertia': 'one_dimensional_deforming'},
        # experiment K: that flow's momentum relative to the body too
        {'internal_inertia': 'one_dimensional', 'internal_flow_momentum': True},
    ],
)
@pytest.mark.parametrize('coupling', ['paper', 'consistent'])
def test_ledger_stores_the_water_insides_kinetic_energy_and_closes_at_second_order(
    coupling, fluid
):
    momentum = fluid.get('internal_flow_momentum', False)
    closures = []
    for dt in (2e-3, 1e-3):
        scene = cone_scene(coupling, dt)
        scene['fluid'].update(fluid)
        model = ShellModel.from_scene(scene)
        state = run(model, 0.6)
        led = model.energy_ledger(state)
        closures.append(abs(led['closure_relative']))
        assert led['stored_kinetic_internal_flow'] > 0.0, led
        # nothing new is booked as an input, nor as created in the consistent coupling
        assert not any(
            k.startswith('in_') and k not in ('in_initial', 'in_actuation_work') for k in led
        )
        if coupling == 'consistent':
            assert not any(k.startswith('created_') for k in led), led
        # K: the consistent coupling stores the cross term rho S U V'; the paper coupling's
        # vehicle force has no reaction on the body-frame wall, so its work is named as created
        assert ('stored_kinetic_internal_cross' in led) == (momentum and coupling == 'consistent')
        assert ('created_unpaid_internal_momentum' in led) == (momentum and coupling == 'paper')
        assert all(
            led[k] != 0.0
            for k in ('stored_kinetic_internal_cross', 'created_unpaid_internal_momentum')
            if k in led
        )
    # measured 2.7e-6 (I), 8.4e-7 (J), 2.7e-6 / 3.1e-6 (K paper / consistent) at 2 ms: a term
    # left out shows as 4e-5 or more (K's cross term left out of the consistent ledger: 3e-6 J
    # against 2e-3 J of input); flipping the sign of K's wall impulse fails the order
    assert closures[0] < 1e-5, closures
    assert closures[0] / max(closures[1], 1e-15) > 3.0, closures


def test_a_meridian_folded_along_the_axis_stops_the_deforming_flow_with_its_cause():
    """One_dimensional_deforming: the 1-D flow needs the section to be a function of z."""
    scene = cone_scene('paper', 1e-3)
    scene['fluid']['internal_inertia'] = 'one_dimensional_deforming'
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    n1 = model.n_nodes
    assert not sk.folded(state, n1)
    state[3 * (n1 - 2) + 1] = -2e-3  # the lip curls back behind the edge's plane
    assert sk.folded(state, n1)
    with pytest.raises(SimulationBlowUp, match='folded back along the axis'):
        model.advance(state, 0.0, 1, Command())


def test_the_option_off_keeps_the_ledger_and_the_motion_of_the_default():
    """
    ``none`` is the default: same motion, no new ledger key.

    This compares one code path with itself; that the kernel change left the default's bits alone
    is guarded by the stored study's bit-for-bit reruns (test_paper000_study.py).
    """
    scene = cone_scene('consistent', 1e-3)
    plain = ShellModel.from_scene(scene)
    scene['fluid']['internal_inertia'] = 'none'
    named = ShellModel.from_scene(scene)
    a, b = run(plain, 0.2), run(named, 0.2)
    assert np.array_equal(a, b)
    assert 'stored_kinetic_internal_flow' not in named.energy_ledger(b)


def _breathing(internal_inertia, perturbation_m=3e-3):
    """Let the study's 20 kPa ellipsoid (paper coupling, 500 Pa s) go from 3 mm inflated."""
    scene = cone_scene(
        'paper',
        1e-3,
        elements=48,
        actuation={'kind': 'none'},
        geometry={
            'kind': 'ellipsoid',
            'semi_axis_axial_m': 0.08,
            'semi_axis_radial_m': 0.03,
            'opening_radius_m': 0.0125,
        },
        initial={'radial_perturbation_m': perturbation_m},
    )
    scene['material']['youngs_modulus_pa'] = 20e3
    scene['fluid']['internal_inertia'] = internal_inertia
    model = ShellModel.from_scene(scene)
    rest = ShellModel.from_scene(dict(scene, initial={'radial_perturbation_m': 0.0}))
    v0 = rest.ref.volume_m3()
    state = model.initial_state()
    times, excess = [], []
    for k in range(1500):
        model.advance(state, k * 1e-3, 1, Command())
        times.append((k + 1) * 1e-3)
        excess.append(model.observe(state, times[-1], Command()).volume_m3 - v0)
    return model, rest, np.array(times), np.array(excess)


def test_the_water_inside_lowers_the_ellipsoids_breathing_to_the_one_mode_estimate():
    """
    Experiment I's estimate: the breathing mode of a uniform hoop strain eps.

    Hoop stiffness ``2 h E S eps^2 / 2`` over the wall area S; kinetic energy of the wall and its
    local added mass, ``(2 h rho_s + C_a rho l_a) int r0^2 dA eps'^2 / 2``, and of the water
    inside, ``rho Lambda (2 V eps')^2 / 2``. Without the water inside the 500 Pa s wall is
    overdamped (no swing through rest); with it the mantle swings, at the estimate within 20 %
    (the assumed uniform strain is not the mode's own shape: the edge and the pole move less).
    """
    model, rest, t, x = _breathing('none')
    assert np.all(x > -1e-4 * x[0]), 'the wall without the water inside should not swing'
    model, rest, t, x = _breathing('one_dimensional')
    crossings = t[1:][np.sign(x[1:]) != np.sign(x[:-1])]
    assert len(crossings) >= 2, crossings
    measured_hz = 1.0 / (2.0 * (crossings[1] - crossings[0]))
    # the linear modes about rest, the water inside in the mass matrix: the swing's damped
    # frequency within 3 % (the crossings are read to the 1 ms step; the start is 3 mm, not small)
    natural_hz, zeta = rest.linear_modes(rest.initial_state())[0]
    assert measured_hz == pytest.approx(natural_hz * math.sqrt(1 - zeta * zeta), rel=0.03)
    assert 0.2 < zeta < 0.4, zeta  # under-damped now; without the water inside: no swing at all
    ref = model.ref
    r0m = 0.5 * (ref.r0[:-1] + ref.r0[1:])
    area = 2.0 * math.pi * r0m * np.diff(ref.X)
    h, rho, rho_s = 1e-3, 1022.0, 1100.0
    stiffness = 2.0 * h * 20e3 * area.sum()
    inertia = (2.0 * h * rho_s + 1.1 * rho * 0.015) * np.sum(area * r0m**2)
    inertia += 4.0 * rho * model.P[sk.P_LAMBDA] * ref.volume_m3() ** 2
    estimate_hz = math.sqrt(stiffness / inertia) / (2.0 * math.pi)
    assert 1.0 < estimate_hz < 2.0  # the routines' range of the study (1.27-1.89 Hz)
    assert measured_hz == pytest.approx(estimate_hz, rel=0.2), (measured_hz, estimate_hz)


@pytest.mark.parametrize(
    'change, message',
    [
        ({'jet': {'outlet': 'ring', 'outlet_radius_m': 0.01}}, 'jet.outlet: ring'),
        ({'coupling': 'paper_code', 'jet': {'outlet': 'free_edge_fixed_nozzle'}}, 'paper_code'),
        ({'simulation': {'dt_s': 1e-6, 'integrator': 'verlet'}}, 'integrator: verlet'),
        ({'terms': {'jet': False}}, 'terms.jet: false'),
    ],
)
def test_internal_inertia_is_refused_where_its_reading_does_not_hold(change, message):
    scene = cone_scene('consistent', 1e-3)
    scene['fluid']['internal_inertia'] = 'one_dimensional'
    scene.update(change)
    with pytest.raises(ModelError, match='fluid.internal_inertia') as err:
        ShellModel.from_scene(scene)
    assert message in str(err.value)


def test_an_unknown_internal_inertia_names_the_value_and_what_is_allowed():
    scene = cone_scene('consistent', 1e-3)
    scene['fluid']['internal_inertia'] = 'slug'
    allowed = 'none, one_dimensional, one_dimensional_deforming'
    with pytest.raises(ModelError, match=f"'slug'.*{allowed}"):
        ShellModel.from_scene(scene)


# ---- experiment K: the same flow's momentum relative to the body, rho S V' along +z


def _momentum_scene(coupling, dt, momentum=True, **fluid):
    scene = cone_scene(coupling, dt)
    scene['fluid'].update(
        internal_inertia='one_dimensional', internal_flow_momentum=momentum, **fluid
    )
    return scene


def test_momentum_length_of_a_closed_cylinder_and_of_paper_001s_ellipsoid():
    """S = int V_b/V dz: L/2 for a cylinder; for the ellipsoid a int F(x)/F(x_e) dx."""
    length, radius = 0.12, 0.02
    cylinder = build_reference_meridian(
        {'kind': 'points', 'points': [[0.0, length], [radius, length], [radius, 0.0]]}, 4000
    )
    assert cylinder.internal_momentum_length_m() == pytest.approx(length / 2.0, rel=1e-4)
    a, b, r_open = 0.08, 0.03, 0.0125
    x_e = math.sqrt(1.0 - (r_open / b) ** 2)

    def flux(x):
        return (1.0 + x) ** 2 * (2.0 - x)

    integral, _ = quad(flux, -1.0, x_e)
    ellipsoid = build_reference_meridian(
        {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': a,
            'semi_axis_radial_m': b,
            'opening_radius_m': r_open,
        },
        4000,
    )
    s_m = ellipsoid.internal_momentum_length_m()
    assert s_m == pytest.approx(a * integral / flux(x_e), rel=1e-4)
    # Cauchy-Schwarz: S^2 <= Lambda V, so the water's kinetic energy stays positive definite
    assert s_m**2 < ellipsoid.internal_inertance_per_m() * ellipsoid.volume_m3()


def test_the_paper_couplings_vehicle_carries_the_water_insides_momentum():
    """
    Paper coupling: the shell is I's bit for bit; the vehicle alone feels -rho S V''.

    Without drag and before any inflow, the two runs' speeds differ by exactly what the water's
    momentum took: sum of m (U_K - U_I) steps = -rho S V'(t), to the midpoint mass's O(dt^2).
    """
    dt = 1e-3
    runs = {}
    for momentum in (False, True):
        model = ShellModel.from_scene(_momentum_scene('paper', dt, momentum, drag_coefficient=0.0))
        state = model.initial_state()
        n1 = model.n_nodes
        rows = []
        for k in range(180):  # the first contraction: the water only leaves
            model.advance(state, k * dt, 1, Command())
            stats = model._eval(state)[0]  # the end-of-step V', which the impulses telescope to
            rows.append((state[6 * n1 + sk.S_U], stats[sk.T_VDOT], stats[sk.T_VOL]))
        runs[momentum] = (state.copy(), np.array(rows))
    assert np.array_equal(runs[False][0][: 6 * n1], runs[True][0][: 6 * n1])
    rows = runs[True][1]
    assert rows[:, 1].max() < 0.0
    rho, s_m = model.P[sk.P_RHO], model.P[sk.P_SMOM]
    body = model.P[sk.P_MBODY] + model.P[sk.P_MSHELL]
    gap = np.concatenate([[0.0], rows[:, 0] - runs[False][1][:, 0]])
    mass = body + rho * np.concatenate([[model.ref.volume_m3()], rows[:, 2]])
    momentum = np.cumsum(0.5 * (mass[1:] + mass[:-1]) * np.diff(gap))
    expected = -rho * s_m * rows[:, 1]
    # measured within 3.1e-8 relative; the run without the term differs by all of it
    np.testing.assert_allclose(momentum[20:], expected[20:], rtol=1e-6)
    assert gap[-1] > 0.0  # the water thrown backwards pushed the body forwards


def test_the_consistent_newton_matrix_carries_the_cross_term():
    """Without the rank-two term the modified Newton needs ~6x the iterations (measured)."""
    iterations = {}
    for momentum in (False, True):
        model = ShellModel.from_scene(_momentum_scene('consistent', 1e-3, momentum))
        state = run(model, 0.6)
        iterations[momentum] = state[6 * model.n_nodes + sk.S_NIT]
    # measured 2085 with the cross term against 2239 without it (12383 with it left out of the
    # Newton matrix)
    assert iterations[True] < 1.25 * iterations[False], iterations


@pytest.mark.parametrize(
    'fluid, message',
    [
        ({'internal_flow_momentum': True}, "one_dimensional \\(the scene has 'none'"),
        (
            {'internal_inertia': 'one_dimensional_deforming', 'internal_flow_momentum': True},
            "has 'one_dimensional_deforming'",
        ),
        (
            {'internal_inertia': 'one_dimensional', 'internal_flow_momentum': 'yes'},
            "'yes' is not a boolean",
        ),
    ],
)
def test_internal_flow_momentum_is_refused_without_the_flow_it_completes(fluid, message):
    scene = cone_scene('consistent', 1e-3)
    scene['fluid'].update(fluid)
    with pytest.raises(ModelError, match='fluid.internal_flow_momentum') as err:
        ShellModel.from_scene(scene)
    assert re.search(message, str(err.value)), str(err.value)
