"""
The shell's two couplings, the mantle-edge nozzle and the muscle's desired-radius functions.

The two couplings are paper 000's and the energy-consistent one; for the couplings, the nozzle and
the functions: what each option does, its ledger, and its refusals.
"""

import math

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.model import ShellModel
import pytest


def cone_scene(
    coupling='paper', dt=1e-3, elements=24, mass=0.335, actuation=None, jet=None, **extra
):
    scene = {
        'model': 'shell',
        'coupling': coupling,
        'simulation': {'dt_s': dt, 'integrator': 'implicit_midpoint'},
        'geometry': {
            'kind': 'cone',
            'length_m': 0.16,
            'base_radius_m': 0.03,
            'tip_radius_m': 0.006,
        },
        'mesh': {'elements': elements},
        'material': {
            'youngs_modulus_pa': 40e3,
            'viscosity_pa_s': 500.0,
            'poisson_ratio': 0.0,
            'half_thickness_m': 1e-3,
            'density_kg_m3': 1100.0,
        },
        'fluid': {
            'density_kg_m3': 1022.0,
            'added_mass_coefficient': 1.1,
            'tangential_drag_coefficient': 0.05,
            'drag_coefficient': 1.7,
        },
        'jet': jet if jet is not None else {'outlet': 'edge', 'thrust_coefficient': 1.0},
        'vehicle': {'mass_kg': mass},
        'actuation': actuation
        or {
            'kind': 'cable',
            'source': 'routine',
            'amplitude': 6.0,
            'distribution': 'rising',
            'frequency_hz': 1.5,
            'contraction_s': 0.2,
            'release_s': 0.3,
        },
    }
    scene.update(extra)
    return scene


def run(model, duration_s):
    state = model.initial_state()
    n = int(round(duration_s / model.dt_s))
    model.advance(state, 0.0, n, Command())
    return state


@pytest.mark.parametrize('coupling', ['paper', 'consistent'])
def test_ledger_closes_at_second_order_and_names_what_the_paper_creates(coupling):
    closures = []
    for dt in (2e-3, 1e-3):
        model = ShellModel.from_scene(cone_scene(coupling, dt))
        led = model.energy_ledger(run(model, 0.6))
        closures.append(abs(led['closure_relative']))
        assert not any(
            k.startswith('in_') and k not in ('in_initial', 'in_actuation_work') for k in led
        )
        if coupling == 'paper':
            # the wall pays nothing for the jet: its kinetic energy flux is booked as created,
            # never as input
            assert led['created_unpaid_jet_kinetic'] > 0.0, led
        else:
            assert 'created_unpaid_jet_kinetic' not in led
    assert closures[0] < 1e-3, closures
    assert closures[0] / max(closures[1], 1e-15) > 3.0, closures  # second order in the step


def test_created_energy_is_the_outflow_jets_kinetic_energy_flux():
    """
    Check created_unpaid_jet_kinetic against the outflow jet's kinetic energy flux.

    created_unpaid_jet_kinetic = sum over outflow steps of dt 1/2 rho A u_j^3
    = -dt 1/2 rho V' u_j^2, from the jet speed and volume rate each step reports (inflow creates
    nothing).
    """
    model = ShellModel.from_scene(cone_scene('paper', 1e-3))
    state = model.initial_state()
    tail = 6 * model.n_nodes
    expected, inflow_steps = 0.0, 0
    for k in range(600):
        model.advance(state, k * 1e-3, 1, Command())
        vdot, uj = state[tail + sk.S_VDOT], state[tail + sk.S_UJ]
        if vdot < 0.0:
            expected += 1e-3 * 0.5 * 1022.0 * -vdot * uj * uj
        else:
            inflow_steps += 1
    assert inflow_steps > 50  # the routine refills, and that creates nothing
    assert model.energy_ledger(state)['created_unpaid_jet_kinetic'] == pytest.approx(
        expected, rel=1e-12
    )


def test_paper_shell_does_not_feel_the_vehicle_consistent_one_does():
    """
    Check that the paper's shell does not feel the vehicle and the consistent one does.

    Paper 000, the coupling paragraph before the state-space form: the vehicle velocity "has been
    used only for the kinematics equation": the shell's motion must not depend on the vehicle's
    mass (hence speed); in the consistent coupling it does (the shell's drag, inertia and the ring
    force see the vehicle).
    """

    def profile(coupling, mass):
        model = ShellModel.from_scene(cone_scene(coupling, mass=mass))
        state = run(model, 0.4)
        return np.concatenate(model.profile(state)), state[6 * model.n_nodes + sk.S_U]

    (p_light, u_light), (p_heavy, u_heavy) = profile('paper', 0.335), profile('paper', 3.35)
    assert np.array_equal(p_light, p_heavy)
    assert u_light > 2.0 * u_heavy > 0.0
    (c_light, _), (c_heavy, _) = profile('consistent', 0.335), profile('consistent', 3.35)
    assert np.max(np.abs(c_light - c_heavy)) > 1e-7


def test_edge_nozzle_area_follows_the_mantle_edge():
    model = ShellModel.from_scene(
        cone_scene(
            'paper',
            actuation={
                'kind': 'cable',
                'source': 'routine',
                'amplitude': 6.0,
                'distribution': 'rising',
                'frequency_hz': 1.5,
                'contraction_s': 0.2,
                'release_s': 0.3,
            },
        )
    )
    state = run(model, 0.15)  # mid-contraction: the rising pull narrows the edge
    r, _ = model.profile(state)
    assert r[-1] < 0.95 * 0.03
    obs = model.observe(state, 0.15, Command())
    vdot = state[6 * model.n_nodes + sk.S_VDOT]
    area = -vdot / obs.jet_speed_m_s  # the outlet area the jet used (at the step's midpoint)
    assert area == pytest.approx(math.pi * r[-1] ** 2, rel=0.02)
    assert area < 0.95**2 * math.pi * 0.03**2
    assert obs.thrust_n == pytest.approx(1022.0 * vdot**2 / area, rel=1e-9)


def test_rigid_ring_outlet_keeps_the_ring_clamped():
    model = ShellModel.from_scene(
        cone_scene('consistent', jet={'outlet': 'ring', 'outlet_radius_m': 0.0125})
    )
    r, _ = model.profile(run(model, 0.15))
    assert r[-1] == 0.03


@pytest.mark.parametrize(
    'scene, message',
    [
        (
            cone_scene(coupling='loose'),
            "coupling: 'loose' is not known; allowed: one of consistent, paper",
        ),
        (
            cone_scene(jet={'outlet': 'edge', 'outlet_radius_m': 0.01}),
            'jet.outlet_radius_m: 0.01 is not used with outlet: edge',
        ),
        (
            cone_scene(jet={'outlet': 'nozzle'}),
            "jet.outlet: 'nozzle' is not known; allowed: one of ring, edge",
        ),
        (
            cone_scene(simulation={'dt_s': 1e-6, 'integrator': 'verlet'}),
            "'verlet' is not available with coupling: paper",
        ),
    ],
)
def test_bad_coupling_options_are_refused_with_the_value(scene, message):
    with pytest.raises(ModelError, match=message.replace('(', r'\(').replace(')', r'\)')):
        ShellModel.from_scene(scene)


#: the muscle of paper 000's Fig. 12 with a constant depth (amplitude x the meridian's max radius)
CONSTANT_DEPTH_MUSCLE = {
    'kind': 'muscle',
    'source': 'routine',
    'amplitude': 0.25,
    'desired_radius': 'constant_depth',
    'taper_fraction': 0.15,
    'frequency_hz': 1.5,
    'contraction_s': 0.2,
    'release_s': 0.3,
}


def test_constant_depth_muscle_moves_the_cone_inwards_by_one_depth():
    """
    Check our reading of Fig. 12 (constant_depth).

    The desired radius is the rest profile moved inwards by one depth (a line parallel to the
    cone's wall) over the middle of the mantle.
    """
    muscle = dict(CONSTANT_DEPTH_MUSCLE)
    model = ShellModel.from_scene(cone_scene('paper', actuation=muscle))
    r0m = model.E[:, sk.E_R0M]
    depth = 0.25 * model.E[:, sk.E_SMUS] * r0m  # r0 - r_desired at full activation
    xm = (np.arange(len(r0m)) + 0.5) / len(r0m)
    middle = (xm > 0.3) & (xm < 0.7)
    assert np.allclose(depth[middle], 0.25 * 0.03, rtol=1e-12)  # the ring's radius, m
    assert np.all(
        1.0 - 0.25 * model.E[:, sk.E_SMUS] >= 0.05 - 1e-12
    )  # capped where the cone is narrow
    proportional = ShellModel.from_scene(
        cone_scene('paper', actuation={**muscle, 'desired_radius': 'proportional'})
    )
    assert np.allclose(proportional.E[middle, sk.E_SMUS], 1.0)


@pytest.mark.parametrize('elements', [6, 12, 24])
@pytest.mark.parametrize('geometry', ['cone', 'ellipsoid'])
def test_constant_depth_takes_the_meridians_largest_radius_not_the_midpoints(elements, geometry):
    """
    The constant depth is ``amplitude x max(r0)`` of the reference meridian's nodes.

    On the cone that is the ring's radius whatever the mesh; the element midpoints' largest radius
    falls half an element's rise short of it (a first-order error in every depth, which made the
    muscle-driven cone converge at first order: benchmarks/results/paper000_study/muscle_depth.md).
    """
    muscle = dict(CONSTANT_DEPTH_MUSCLE)
    scene = cone_scene('paper', elements=elements, actuation=muscle)
    if geometry == 'ellipsoid':
        scene['geometry'] = {
            'kind': 'ellipsoid',
            'semi_axis_axial_m': 0.09,
            'semi_axis_radial_m': 0.035,
            'opening_radius_m': 0.0125,
        }
    model = ShellModel.from_scene(scene)
    r0m = model.E[:, sk.E_R0M]
    depth = 0.25 * model.E[:, sk.E_SMUS] * r0m
    xm = (np.arange(len(r0m)) + 0.5) / len(r0m)
    middle = (xm > 0.3) & (xm < 0.7)
    largest = float(model.ref.r0.max())
    if geometry == 'cone':
        assert largest == 0.03  # the ring's radius, m
        assert r0m.max() < largest - 0.2 * (r0m[-1] - r0m[-2])  # the midpoints fall short
    assert np.allclose(depth[middle], 0.25 * largest, rtol=1e-12)


def test_constant_depth_to_edge_muscle_narrows_the_free_edge():
    """
    Check the third reading of Fig. 12 (`constant_depth_to_edge`).

    The constant depth is held up to the free edge (tapered at the pole only), so the muscle
    narrows the cone's nozzle; the study's `constant_depth` tapers to zero at the edge and leaves
    the nozzle open.
    """
    muscle = {
        'kind': 'muscle',
        'source': 'routine',
        'amplitude': 0.25,
        'desired_radius': 'constant_depth_to_edge',
        'taper_fraction': 0.15,
        'frequency_hz': 1.5,
        'contraction_s': 0.2,
        'release_s': 0.3,
    }
    to_edge = ShellModel.from_scene(cone_scene('paper', actuation=muscle))
    r0m = to_edge.E[:, sk.E_R0M]
    depth = 0.25 * to_edge.E[:, sk.E_SMUS] * r0m
    assert depth[-1] == pytest.approx(0.25 * 0.03, rel=1e-12)  # full depth at the edge element
    assert depth[0] < 0.1 * depth[-1]  # still tapered at the pole
    tapered = ShellModel.from_scene(
        cone_scene('paper', actuation={**muscle, 'desired_radius': 'constant_depth'})
    )
    assert tapered.E[-1, sk.E_SMUS] < 0.1
    xm = (np.arange(len(r0m)) + 0.5) / len(r0m)
    assert np.array_equal(
        to_edge.E[xm < 0.5, sk.E_SMUS], tapered.E[xm < 0.5, sk.E_SMUS]
    )  # same elsewhere
    r_edge, r_tapered = (
        to_edge.profile(run(to_edge, 0.2))[0][-1],
        tapered.profile(run(tapered, 0.2))[0][-1],
    )
    assert r_edge < 0.85 * 0.03, r_edge  # at full activation the nozzle has narrowed by > 15 %
    assert r_tapered > 0.98 * 0.03, r_tapered  # the tapered function leaves it open
    # the narrower nozzle is what the jet uses: the outlet area follows the edge
    state = run(to_edge, 0.15)
    vdot = state[6 * to_edge.n_nodes + sk.S_VDOT]
    obs = to_edge.observe(state, 0.15, Command())
    assert vdot < 0.0
    assert -vdot / obs.jet_speed_m_s < math.pi * (0.95 * 0.03) ** 2


def test_fixed_nozzle_with_a_free_edge_keeps_the_exit_area():
    """
    Check `free_edge_fixed_nozzle` (the authors' later code: Area_out = pi Rn^2, Rn = 12.5 mm).

    The edge moves as with `edge`, the jet leaves through the fixed nozzle.
    """
    jet = {
        'outlet': 'free_edge_fixed_nozzle',
        'outlet_radius_m': 0.0125,
        'thrust_coefficient': 1.0,
    }
    model = ShellModel.from_scene(cone_scene('paper', jet=jet))
    state = run(model, 0.15)
    r, _ = model.profile(state)
    assert r[-1] < 0.95 * 0.03  # the rising pull narrows the free edge ...
    vdot = state[6 * model.n_nodes + sk.S_VDOT]
    obs = model.observe(state, 0.15, Command())
    assert vdot < 0.0
    # ... not the nozzle
    assert -vdot / obs.jet_speed_m_s == pytest.approx(math.pi * 0.0125**2, rel=1e-9)
    edge = ShellModel.from_scene(cone_scene('paper'))
    # in the paper coupling no cavity pressure acts on the wall, so the exit area does not change
    # the shell
    assert np.array_equal(model.profile(state)[0], edge.profile(run(edge, 0.15))[0])


def test_paper_code_clamps_the_pole_and_frees_the_edge():
    """
    Check experiment E, `coupling: paper_code`.

    The authors' code, docs/theory/shell.md "Experiment E": the body holds the polar cap up to
    the rim of the code's pi/4 hole (sigmas_o = zeros(6,1) at X = 0), the open edge carries no
    wrench and moves in r, z and theta; thrust, refill force and
    drag ride on the wall and reach the vehicle through the rim; the ledger names what the scheme
    creates and closes.
    """
    jet = {
        'outlet': 'free_edge_fixed_nozzle',
        'outlet_radius_m': 0.0125,
        'thrust_coefficient': 1.0,
    }
    model = ShellModel.from_scene(cone_scene('paper_code', jet=jet))
    nd = model.Nd
    k = model.code_rim  # the rim of the code's pi/4 hole: the wall has turned by pi/4 there
    assert 0 < k < model.n_nodes // 4 and abs(model.ref.theta0[k]) >= math.pi / 4 > abs(
        model.ref.theta0[k - 1]
    )
    assert np.all(
        nd[: k + 1, [sk.N_FIXR, sk.N_FIXZ, sk.N_FIXT]] == 1.0
    )  # polar cap and rim clamped
    assert np.all(nd[k + 1:, sk.N_FIXZ] == 0.0) and not np.any(
        nd[: k + 1, sk.N_WC]
    )  # cable on the wall only
    assert nd[-1, sk.N_FIXR] == nd[-1, sk.N_FIXZ] == nd[-1, sk.N_FIXT] == 0.0  # edge free
    assert np.allclose(nd[:, sk.N_MRR], 2.1 * model.node_mass)  # 1.1 x own mass, r and z
    assert np.allclose(nd[:, sk.N_MZZ], 2.1 * model.node_mass) and not np.any(nd[:, sk.N_MRZ])
    state = run(model, 0.15)
    r, z = model.profile(state)
    assert np.array_equal(z[: k + 1], model.ref.z0[: k + 1]) and np.array_equal(
        r[: k + 1], model.ref.r0[: k + 1]
    )
    assert abs(z[-1] - model.ref.z0[-1]) > 1e-6  # the edge moves along the axis ...
    assert r[-1] < 0.99 * 0.03  # ... and radially
    tail = 6 * model.n_nodes
    vdot = state[tail + sk.S_VDOT]
    assert vdot < 0.0 and state[tail + sk.S_U] > 0.0  # expelling, and the body moves forward
    obs = model.observe(state, 0.15, Command())
    assert -vdot / obs.jet_speed_m_s == pytest.approx(
        math.pi * 0.0125**2, rel=1e-9
    )  # fixed nozzle
    led = model.energy_ledger(state)
    assert led['created_unpaid_jet_kinetic'] > 0.0 and 'created_wall_loads' in led
    assert abs(led['closure_relative']) < 1e-4, led
    with pytest.raises(ModelError, match='not available with coupling: paper_code'):
        ShellModel.from_scene(cone_scene('paper_code', jet={'outlet': 'edge'}))
