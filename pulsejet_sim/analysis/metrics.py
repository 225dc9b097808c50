"""
The swimming figures of a run, defined once: speeds, distance, burst speed, cost of transport.

All SI: times in s, velocities in m/s (positive forward), distances in m, work in J, masses in kg.

Three mean speeds live here side by side because they answer different questions, and the
tables stored by the tools were computed with each; none replaces another:

- ``sample_mean_speed_m_s``: the mean of |v| over equally spaced samples (``pulsejet sweep``,
  over the published samples of a run). Cheap, needs no times; equal to the time mean when the
  samples are equally spaced, up to the end samples.
- ``time_mean_speed_m_s``: the time average of |v| by the trapezoidal rule over the samples'
  span (``pulsejet summary`` of a recording, whose messages need not be equally spaced).
- ``window_mean_velocity_m_s``: the time average of the signed forward velocity over a window
  (``pulsejet fit``, the figure papers report: backward drift during refill counts against it).

Two distances, for the same reason: ``distance_from_samples_m`` (the sum of the published samples
times the publication period, as a sweep and the routine optimiser measure a run) and
``distance_m`` (the trapezoidal integral of v over the recorded times, as the summary measures a
recording).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

GRAVITY_M_S2 = 9.81  # standard gravity in the cost of transport's weight m g


def trapezoid(y: np.ndarray, t: np.ndarray) -> float:
    """Return the trapezoidal integral of samples y over times t; 0 with fewer than two samples."""
    if len(t) < 2:
        return 0.0
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


def sample_mean_speed_m_s(velocities_m_s: Sequence[float]) -> float:
    """
    Return the mean of |v| over equally spaced samples (m/s), summed in sample order.

    Use for a run's published samples (a sweep row); it needs at least one sample.
    """
    return sum(abs(v) for v in velocities_m_s) / len(velocities_m_s)


def time_mean_speed_m_s(t_s: np.ndarray, v_m_s: np.ndarray) -> float:
    """
    Return the time average of |v| over the samples' span (m/s), trapezoidal in time.

    Use for a recording whose samples need not be equally spaced; a single instant (zero span)
    gives the mean of its |v| samples.
    """
    span = t_s[-1] - t_s[0]
    return trapezoid(np.abs(v_m_s), t_s) / span if span > 0 else float(np.abs(v_m_s).mean())


def window_mean_velocity_m_s(t_s: np.ndarray, v_m_s: np.ndarray) -> float:
    """
    Return the time average of the signed forward velocity over t_s[0]..t_s[-1] (m/s).

    Trapezoidal in time. Use for the mean swimming speed a paper reports over whole strokes: a
    backward drift counts against it. Needs at least two samples of distinct times.
    """
    v = v_m_s
    return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t_s)) / (t_s[-1] - t_s[0]))


def peak_speed_m_s(velocities_m_s: Sequence[float] | np.ndarray) -> float:
    """Return the largest |v| of the samples (m/s), forward or backward."""
    return float(np.max(np.abs(np.asarray(velocities_m_s, dtype=float))))


def burst_speed_m_s(v_m_s: np.ndarray) -> float:
    """Return the largest forward (signed) velocity sample, m/s (a backward surge is no burst)."""
    return float(v_m_s.max())


def distance_from_samples_m(velocities_m_s: Sequence[float], sample_period_s: float) -> float:
    """
    Return the net forward distance (m): the sum of equally spaced samples times their period.

    Summed in sample order (Python's sum), as the stored sweep and optimisation tables were.
    """
    return sum(velocities_m_s) * sample_period_s


def distance_m(t_s: np.ndarray, v_m_s: np.ndarray) -> float:
    """Return the net forward distance (m): the trapezoidal integral of v over the times."""
    return trapezoid(v_m_s, t_s)


def cost_of_transport(work_j, distance_m, mass_kg, min_distance_m=0.0):
    """
    Return the cost of transport W / (m g max(d, d_min)), dimensionless (arrays or scalars).

    work_j: the actuation work put in (J); distance_m: the net forward distance (m); mass_kg:
    the mass moved, which the caller chooses and states (the environments: the vehicle with the
    water of its rest cavity; the routine optimiser: the dry mass plus the time-mean water in the
    cavity); min_distance_m keeps it finite while the vehicle has not moved forward (0: none, the
    caller then handles d <= 0). Returns a numpy scalar or array.
    """
    return np.asarray(work_j) / (mass_kg * GRAVITY_M_S2 * np.maximum(distance_m, min_distance_m))
