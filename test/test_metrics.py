"""
The swimming figures of analysis.metrics, each against its definition on a signal worked by hand.

A pulsed swimmer surges forward and drifts back: v = 0.2, -0.1, 0.2, -0.1, 0.2 m/s at t = 0, 1, 2,
3, 4 s. The three mean speeds then differ, and each tool's stored number is the one it names.
"""

import math

import numpy as np
from pulsejet_sim.analysis import metrics
from pulsejet_sim.models.lumped import model as lumped
from pulsejet_sim.scene import load_scene
import pytest

T = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
V = np.array([0.2, -0.1, 0.2, -0.1, 0.2])


def test_the_three_mean_speeds_are_distinct_quantities():
    # sample mean of |v|: (0.2 + 0.1 + 0.2 + 0.1 + 0.2) / 5
    assert metrics.sample_mean_speed_m_s(list(V)) == pytest.approx(0.16, abs=1e-15)
    # time mean of |v| (trapezoid): four intervals of mean 0.15 m/s over 4 s
    assert metrics.time_mean_speed_m_s(T, V) == pytest.approx(0.15, abs=1e-15)
    # time mean of the signed v: four intervals of mean 0.05 m/s over 4 s
    assert metrics.window_mean_velocity_m_s(T, V) == pytest.approx(0.05, abs=1e-15)
    # one instant: the mean of its |v|
    assert metrics.time_mean_speed_m_s(T[:1], V[:1]) == pytest.approx(0.2)


def test_distances_peak_and_burst():
    assert metrics.distance_m(T, V) == pytest.approx(0.2, abs=1e-15)  # trapezoid
    assert metrics.distance_from_samples_m(list(V), 1.0) == pytest.approx(0.4, abs=1e-15)
    assert metrics.distance_m(T[:1], V[:1]) == 0.0
    backward = np.array([0.1, -0.3, 0.2])
    assert metrics.peak_speed_m_s(backward) == 0.3  # |v|: the backward surge counts
    assert metrics.burst_speed_m_s(backward) == 0.2  # forward only


def test_cost_of_transport_states_its_mass_and_floor():
    # 9.81 J moving 1 kg by 1 m: W / (m g d) = 1
    assert metrics.cost_of_transport(9.81, 1.0, 1.0) == pytest.approx(1.0)
    # the floor keeps it finite before the vehicle moved forward; arrays work element-wise
    cot = metrics.cost_of_transport(np.array([0.981, 0.981]), np.array([-1.0, 0.5]), 2.0, 0.1)
    assert cot == pytest.approx([0.5, 0.1])


def test_lumped_readings_are_the_models_own_numbers():
    model = load_scene('pump_cycle').model
    state = model.initial_state()
    obs = model.observe(state, 0.0, model.initial_command)
    assert lumped.cavity_volume_m3(state, model.params) == obs.volume_m3
    assert lumped.minor_semi_axis_m(state) == obs.mantle_radius_m
    assert lumped.velocity_m_s(state) == obs.velocity_m_s == 0.0
    assert lumped.pump_flow_m3_s(state) == obs.pump_flow_m3_s
    assert lumped.valve_opening(state) == obs.valve_opening
    assert lumped.pump_work_j(state) == model.energy_ledger(state)['in_actuation_work'] == 0.0
    assert model.dry_mass_kg == lumped.dry_mass_kg(model.params) > 0.0
    # batches read row by row
    batch = np.stack([state, state])
    assert lumped.cavity_volume_m3(batch, np.stack([model.params] * 2)).tolist() == [
        obs.volume_m3
    ] * 2
    # a perturbed shape with the valve shut keeps the cavity sealed: db/dt = Q_p / (8/3 pi a b)
    shut = load_scene(
        'pump_cycle', {'actuator': {'initial_valve_opening': 0.0, 'initial_pump_flow_m3_s': 1e-4}}
    ).model
    y = shut.initial_state()
    lumped.scale_minor_semi_axis(y, shut.params, 1.01)
    a, b = lumped.major_semi_axis_m(shut.params), lumped.minor_semi_axis_m(y)
    sealed_rate = 1e-4 / (8.0 / 3.0 * math.pi * a * b)
    assert lumped.minor_semi_axis_rate_m_s(y) == pytest.approx(sealed_rate)
