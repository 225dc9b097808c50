"""
Rewards of the pulsejet environments (all SI), chosen by name.

Each works on arrays, so the single and the vector environments share it.

- ``distance``: metres swum forward during the control period, ``x(t+T) - x(t)``.
- ``mean_speed``: mean forward speed over the control period, ``(x(t+T) - x(t)) / T`` (m/s).
- ``cost_of_transport``: minus the increase of the running cost of transport, so that the episode's
  return is minus the cost of transport of the whole episode (the sum telescopes):
  ``CoT(t) = W_act(t) / (m g max(x(t) - x(0), d_min))`` (``analysis.metrics.cost_of_transport``),
  ``W_act`` the actuation work put in since the reset (the energy ledger's ``in_actuation_work``,
  J), ``m`` the mass the environment states (lumped: solid mass plus the water of the rest cavity,
  ``lumped_env.lumped_mass_kg``; shell: ``vehicle.mass_kg``), ``g = 9.81 m/s^2``, ``d_min``
  (default 0.01 m) keeps it finite while the robot has not moved forward.
- ``track_speed``: minus the absolute error of the mean speed over the period against
  ``target_speed_m_s`` (m/s).
"""

from __future__ import annotations

import numpy as np
from pulsejet_sim.analysis import metrics

REWARDS = ('distance', 'mean_speed', 'cost_of_transport', 'track_speed')


def check_reward(name: str) -> str:
    if name not in REWARDS:
        raise ValueError(f'reward={name!r} rejected; allowed: one of {", ".join(REWARDS)}')
    return name


def reward(
    name: str, *, x0, x1, x_start, work0, work1, period_s, mass_kg, target_speed_m_s, d_min_m
):
    """
    Return the reward of one control period (arrays or floats).

    Inputs: positions before/after (m), the episode's start position, actuation work before/after
    (J).
    """
    if name == 'distance':
        return x1 - x0
    if name == 'mean_speed':
        return (x1 - x0) / period_s
    if name == 'track_speed':
        return -np.abs((x1 - x0) / period_s - target_speed_m_s)
    return -(
        metrics.cost_of_transport(work1, x1 - x_start, mass_kg, d_min_m)
        - metrics.cost_of_transport(work0, x0 - x_start, mass_kg, d_min_m)
    )
