"""
The cable routine has one definition: the shell's kernels and CableRoutine pull with the same bits.

models/cable_pulse.py is evaluated inside the numba kernels (shell.kernels.routine, with the
timing packed in the parameter vector) and by pulsejet_sim.routines.CableRoutine (controller_node,
the offline runner). A command-driven run must pull exactly as the model's own routine at the
same times: compared bit for bit over a grid of times and timings, edges included.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
from pulsejet_sim.models.shell import kernels as sk
from pulsejet_sim.models.shell.model import ShellModel
from pulsejet_sim.routines import CableRoutine
import pytest
import yaml

ROBOT = yaml.safe_load((Path(__file__).resolve().parent.parent / 'config' / 'shell_robot.yaml')
                       .read_text())

# (frequency_hz, contraction_s, release_s, start_delay_s): the robot's, a ramp that starts late, a
# rise and fall filling the whole period (the duty limit), a short sharp pull, slow and long ones
TIMINGS = [
    (1.6, 0.2, 0.3, 0.0),
    (1.6, 0.2, 0.3, 0.37),
    (2.0, 0.2, 0.3, 0.0),  # contraction + release = the period
    (2.5, 0.15, 0.25, 0.1),  # the same at 2.5 Hz, with a delay
    (10.0, 0.001, 0.099, 0.0),  # the shortest rise, the rest of the period falling
    (0.3, 1.0, 2.0, 1e-3),
    (7.0, 0.05, 0.01, 0.2),
]


def edge_times(frequency_hz, contraction_s, release_s, start_delay_s, periods=4):
    """Return the phase edges of the first periods, one ulp either side, and a regular grid."""
    period = 1.0 / frequency_hz
    edges = []
    for k in range(periods):
        start = start_delay_s + k * period
        edges += [start, start + contraction_s, start + contraction_s + release_s,
                  start + period]
    edges += [0.0, start_delay_s, 1e-12]
    times = []
    for t in edges:
        times += [np.nextafter(t, -np.inf), t, np.nextafter(t, np.inf)]
    times += list(np.linspace(0.0, start_delay_s + periods * period, 997))
    times += [start_delay_s + 1000.5 * period, 1e4 + 0.123]  # far on: many periods folded
    return [float(t) for t in times if t >= 0.0]


def packed(frequency_hz, contraction_s, release_s, start_delay_s, pulse):
    """Return a parameter vector with the routine's timing where the kernels read it."""
    P = np.zeros(sk.N_PARAMS)
    P[sk.P_FREQ] = frequency_hz
    P[sk.P_TC] = contraction_s
    P[sk.P_TR] = release_s
    P[sk.P_DELAY] = start_delay_s
    P[sk.P_PULSE] = sk.PULSE_TRIANGLE if pulse == 'triangle' else sk.PULSE_HALF_COSINE
    return P


@pytest.mark.parametrize('pulse', ['half_cosine', 'triangle'])
@pytest.mark.parametrize('timing', TIMINGS)
def test_the_kernels_routine_and_cable_routine_are_bit_identical(timing, pulse):
    P = packed(*timing, pulse)
    routine = CableRoutine(8.0, *timing, pulse)
    times = edge_times(*timing)
    kernel = np.array([sk.routine(t, P)[0] for t in times])
    controller = np.array([routine.activation(t) for t in times])
    assert kernel.tobytes() == controller.tobytes()
    assert np.all((kernel >= 0.0) & (kernel <= 1.0))
    frequency_hz, contraction_s, release_s, start_delay_s = timing
    # the edges themselves: at rest before the delay and at each period's start, full pull at the
    # end of the rise, slack once the release is over
    assert routine.activation(np.nextafter(start_delay_s, -np.inf)) == 0.0
    assert routine.activation(start_delay_s) == 0.0
    assert routine.activation(start_delay_s + contraction_s) == pytest.approx(1.0, abs=1e-12)
    if contraction_s + release_s < 1.0 / frequency_hz:
        rest = start_delay_s + 0.5 * (contraction_s + release_s + 1.0 / frequency_hz)
        assert routine.activation(rest) == 0.0


@pytest.mark.parametrize('pulse', ['half_cosine', 'triangle'])
def test_a_shell_scenes_built_in_pull_and_its_command_driven_pull_are_bit_identical(pulse):
    """What ShellModel applies itself and what controller_node sends for the same scene."""
    scene = copy.deepcopy(ROBOT)
    scene['actuation'].update(pulse=pulse, start_delay_s=0.05, contraction_s=0.25,
                              release_s=0.375)
    model = ShellModel.from_scene(scene)
    act = model.actuation
    controller = CableRoutine(act['amplitude'], act['frequency_hz'], act['contraction_s'],
                              act['release_s'], act['start_delay_s'], act['pulse'])
    times = edge_times(act['frequency_hz'], act['contraction_s'], act['release_s'],
                       act['start_delay_s'])
    built_in = [model.routine_command(t).cable_force_n for t in times]
    commanded = [controller.command(t).cable_force_n for t in times]
    assert np.array(built_in).tobytes() == np.array(commanded).tobytes()
    assert max(built_in) == pytest.approx(act['amplitude'])
    quarter = act['start_delay_s'] + 0.25 * act['contraction_s']
    expected = {'half_cosine': 0.5 * (1 - math.cos(math.pi / 4)), 'triangle': 0.25}[pulse]
    assert controller.activation(quarter) == pytest.approx(expected, rel=1e-15)
