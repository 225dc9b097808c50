"""The pump/valve routine is a pure state machine: same inputs, same commands."""

from pulsejet_sim.core.model_io import ModelError
from pulsejet_sim.routines import PumpValveRoutine
import pytest


def test_timed_cycle_phases_and_repeat():
    r = PumpValveRoutine(inflate_s=1.0, pump_flow_m3_s=1e-3, hold_s=0.5, jet_s=2.0, cycles=2)
    at = lambda t: r.command(t)  # noqa: E731
    assert at(0.0).pump_flow_m3_s == 1e-3 and at(0.0).valve_opening == 0.0  # inflate, valve shut
    assert at(0.99).pump_flow_m3_s == 1e-3
    assert at(1.2).pump_flow_m3_s == 0.0 and at(1.2).valve_opening == 0.0  # hold
    assert at(1.6).valve_opening == 1.0 and at(1.6).pump_flow_m3_s == 0.0  # jet
    assert at(3.6).pump_flow_m3_s == 1e-3  # second cycle
    assert at(7.5).valve_opening == 1.0 and at(7.5).pump_flow_m3_s == 0.0  # done: valve left open
    assert r.cycle == 2


def test_target_volume_ends_inflation_and_time_limit_still_applies():
    r = PumpValveRoutine(
        inflate_s=5.0, target_volume_m3=2e-3, pump_flow_m3_s=1e-3, hold_s=0.0, jet_s=1.0
    )
    assert r.command(0.5, volume_m3=1.0e-3).pump_flow_m3_s == 1e-3
    assert r.command(0.6, volume_m3=2.1e-3).valve_opening == 1.0  # target reached, jet
    r2 = PumpValveRoutine(
        inflate_s=1.0, target_volume_m3=9.0, pump_flow_m3_s=1e-3, hold_s=0.0, jet_s=1.0
    )
    assert r2.command(0.5, volume_m3=1e-3).pump_flow_m3_s == 1e-3
    assert r2.command(1.01, volume_m3=1e-3).valve_opening == 1.0  # time limit


def test_coarse_caller_does_not_skip_or_stretch_phases():
    fine = PumpValveRoutine(inflate_s=1.0, pump_flow_m3_s=1e-3, hold_s=0.3, jet_s=0.7)
    coarse = PumpValveRoutine(inflate_s=1.0, pump_flow_m3_s=1e-3, hold_s=0.3, jet_s=0.7)
    for i in range(401):
        fine.command(i * 0.01)
    coarse.command(0.0)
    assert coarse.command(4.005) == fine.command(4.005)


def test_bad_routine_config_names_the_key():
    with pytest.raises(ModelError, match='routine.pump_flow_m3_s.*-1'):
        PumpValveRoutine.from_config({'pump_flow_m3_s': -1})
    with pytest.raises(ModelError, match='routine.speed: unknown key'):
        PumpValveRoutine.from_config({'speed': 3})


def test_cable_routine_pulls_with_half_cosines_and_rests():
    from pulsejet_sim.routines import CableRoutine, routine_from_scene

    r = routine_from_scene(
        {
            'kind': 'cable',
            'amplitude_n': 10.0,
            'frequency_hz': 1.0,
            'contraction_s': 0.2,
            'release_s': 0.4,
        }
    )
    assert isinstance(r, CableRoutine)
    assert r.command(0.0).cable_force_n == 0.0
    assert r.command(0.1).cable_force_n == pytest.approx(5.0)  # half-way up
    assert r.command(0.2).cable_force_n == pytest.approx(10.0)  # peak
    assert r.command(0.4).cable_force_n == pytest.approx(5.0)  # half-way down
    assert r.command(0.8).cable_force_n == 0.0  # slack
    assert r.command(1.2).cable_force_n == pytest.approx(10.0)  # periodic
    with pytest.raises(ModelError, match='exceeds the period'):
        CableRoutine(frequency_hz=5.0, contraction_s=0.2, release_s=0.3)
    triangle = CableRoutine(10.0, 1.0, 0.5, 0.5, 0.0, 'triangle')  # the authors' code's pulse
    assert [triangle.command(t).cable_force_n for t in (0.1, 0.5, 0.6, 1.0)] == pytest.approx(
        [2.0, 10.0, 8.0, 0.0]
    )
    with pytest.raises(ModelError, match="routine.pulse.*'saw'"):
        routine_from_scene({'kind': 'cable', 'pulse': 'saw'})
