"""
The exit's vena contracta (``jet.contraction_coefficient``, docs/theory/shell.md).

Cc = 1 is the shipped model to the bit; Cc < 1 is the outlet of area Cc A (the jet leaves at
Q / (Cc A), the cavity pays 1/Cc^2 the pressure, the thrust is 1/Cc times larger) with the refill
opening unchanged, and the ledger still closes at the integrator's second order.
"""

import copy
import math
import pathlib

import numpy as np
from pulsejet_sim.core.model_io import Command, ModelError
from pulsejet_sim.core.schema import read_yaml_file
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.model import ShellModel
import pytest

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'
# the cable robot's outlet (radius 12.5 mm) in its cylinder (radius 21.9 mm), sharp-edged:
# 1/Cc = 1 + 0.622 (1 - 0.215 beta^2 - 0.785 beta^5), beta = 12.5 / 21.9 (docs/theory/shell.md)
CC = 0.6456


def robot(jet=None, **simulation):
    scene = read_yaml_file(CONFIG / 'shell_robot.yaml')
    scene['jet'] = {**scene['jet'], **(jet or {})}
    scene['simulation'] = {**scene['simulation'], **simulation}
    return copy.deepcopy(scene)


def run(scene, seconds):
    model = ShellModel.from_scene(scene)
    state = model.initial_state()
    model.advance(state, 0.0, int(round(seconds / model.dt_s)), Command())
    return model, state


def test_cc_one_is_the_shipped_model_to_the_bit():
    (_, a), (_, b) = run(robot(), 1.0), run(robot({'contraction_coefficient': 1.0}), 1.0)
    assert np.array_equal(a, b)


def test_the_jet_leaves_through_cc_times_the_outlet():
    shipped = ShellModel.from_scene(robot())
    contracted = ShellModel.from_scene(robot({'contraction_coefficient': CC}))
    area = math.pi * 0.0125**2
    assert shipped.P[sk.P_AOUT] == area
    assert contracted.P[sk.P_AOUT] == pytest.approx(CC * area, rel=1e-15)
    # the refill opening stays the outlet's: only the outflow contracts
    assert contracted.P[sk.P_AIN] == shipped.P[sk.P_AIN]
    rho, q = contracted.P[sk.P_RHO], -2e-4  # m^3/s out
    p0, u0, thrust0, *_ = sk.jet_terms(q, 0.1, shipped.P, shipped.P[sk.P_AOUT])
    p1, u1, thrust1, *_ = sk.jet_terms(q, 0.1, contracted.P, contracted.P[sk.P_AOUT])
    assert u1 == pytest.approx(-q / (CC * area), rel=1e-12)
    assert p1 == pytest.approx(0.5 * rho * u1**2, rel=1e-12)
    assert p1 / p0 == pytest.approx(1 / CC**2, rel=1e-12)
    # the orifice's discharge law, velocity coefficient 1: Q = Cc A sqrt(2 p / rho)
    assert -q == pytest.approx(CC * area * math.sqrt(2 * p1 / rho), rel=1e-12)
    assert thrust1 / thrust0 == pytest.approx(1 / CC, rel=1e-12)


def test_same_as_an_outlet_of_the_vena_contractas_radius():
    # the key is the vena contracta and nothing else: a run with it matches a run whose outlet
    # has the vena contracta's radius (and the shipped refill opening), to the area's rounding
    inlet = math.pi * 0.0125**2 + 3 * math.pi * 0.01**2
    _, a = run(robot({'contraction_coefficient': CC}), 1.0)
    _, b = run(robot({'outlet_radius_m': 0.0125 * math.sqrt(CC), 'inlet_area_m2': inlet}), 1.0)
    assert np.allclose(a, b, rtol=1e-9, atol=1e-12)
    _, shipped = run(robot(), 1.0)
    assert not np.allclose(a, shipped, rtol=1e-3, atol=0.0)


def test_ledger_closes_at_second_order_with_the_vena_contracta():
    closures = []
    for dt in (1e-2, 5e-3):
        model, state = run(
            robot({'contraction_coefficient': CC}, dt_s=dt, newton_tolerance=1e-11), 2.0
        )
        led = model.energy_ledger(state)
        assert led['in_actuation_work'] > 0 and led['out_jet_kinetic'] > 0
        closures.append(led['closure_relative'])
    print('closure', closures)
    assert abs(closures[0]) < 1e-4
    assert closures[0] / closures[1] == pytest.approx(4.0, rel=0.1)


@pytest.mark.parametrize(
    'jet, words',
    [
        ({'contraction_coefficient': 0.3}, ['0.3', '[0.5, 1]']),
        ({'contraction_coefficient': 1.2}, ['1.2', '[0.5, 1]']),
        ({'contraction_coefficient': 0.7, 'outlet': 'edge'}, ['0.7', 'outlet: edge', 'allowed']),
        (
            {'contraction_coefficient': 0.7, 'starting_jet': True},
            ['0.7', 'starting_jet', 'twice', 'allowed'],
        ),
        (
            {
                'contraction_coefficient': 0.7,
                'outlet': 'free_edge_fixed_nozzle',
                'coupling': 'paper',
            },
            ['0.7', 'coupling: paper', 'allowed'],
        ),
    ],
)
def test_what_it_cannot_do_is_refused_with_what_is_allowed(jet, words):
    jet = dict(jet)
    coupling = jet.pop('coupling', None)
    scene = robot(jet)
    if coupling:
        scene['coupling'] = coupling
    if jet.get('outlet') == 'edge':
        del scene['jet']['outlet_radius_m']
    with pytest.raises(ModelError) as err:
        ShellModel.from_scene(scene)
    for word in words:
        assert word in str(err.value)
