"""
Starting-jet thrust beyond the slug model: the forming vortex ring's exit over-pressure.

Scene switch ``jet.starting_jet: true`` of the shell model (consistent coupling, implicit
integrators; default false, which leaves every result bit for bit).  Theory, sources and limits:
docs/theory/starting_jet.md.  No ROS, no Python objects in the kernels.

Model
-----
The quasi-steady slug model gives the jet the thrust ``rho A u^2`` and charges the cavity the
dynamic pressure ``rho u^2/2``.  A starting jet's measured impulse exceeds the slug impulse
``I_slug = rho A int u^2 dt`` while a vortex ring forms (Krueger & Gharib 2003, Phys. Fluids 15,
1271); the excess is the impulse of the nozzle exit over-pressure, which Krueger (2005, J. Fluid
Mech. 545, 427) models by the added mass of a disc of the nozzle's radius started with the jet,
``m_d = (8/3) rho R^3`` (the potential-flow added mass of a circular disc moving broadside): the
ambient water ahead of the nozzle that the forming ring sets moving.  Here that reads::

    p_ex A = m_d du_j/dt        while the ring forms and the jet accelerates,
    p_ex   = 0                  while it decelerates, and after pinch-off.

*Why one-sided.*  The water that the over-pressure accelerates leaves with the ring (Olcay &
Krueger, Theor. Comput. Fluid Dyn., doi:10.1007/s00162-009-0173-y, abstract: the ejected fluid
exchanges its momentum mostly with the added mass during ejection, and that momentum is carried
by the ring), so the deceleration does not take it back: the pulse's over-pressure impulse is
``m_d u_peak`` (the impulsive start's ``(8/3) rho R^3 U`` of Krueger 2005).  Moslemi (2020,
arXiv:2101.00075) finds by simulation an under-pressure during the deceleration of tube-nozzle
jets and no net gain; this model follows the force-balance measurements instead
(docs/theory/starting_jet.md, "Limits").

*Pinch-off.*  The formation time of the current pulse, ``T* = int u_j / D dt`` (Gharib, Rambod &
Shariff 1998, J. Fluid Mech. 360, 121: the stroke ratio L/D of a piston-cylinder; Dabiri & Gharib
2005, J. Fluid Mech. 538, not looked up here, integrate ``u/D(t)`` for a nozzle whose diameter
changes), grows while water leaves and is
reset to 0 when the outflow stops (the volume rate is no longer negative: the valve closes or the
mantle refills).  A step that starts at ``T* >= F`` (the formation number, 4 by default, Gharib
et al. 1998) carries no over-pressure: the ring has pinched off and the trailing jet is
quasi-steady.

*Energy.*  The over-pressure acts on the cavity wall (the cavity pressure rises by ``p_ex``, so
the wall and the actuator pay), and ``A p_ex`` is added to the thrust on the vehicle.  The work
that leaves the shell-vehicle system, ``A p_ex (u_j - U)`` (the exit pressure's work on the water
that crosses the exit, in the earth frame), is booked as jet output (the ring's kinetic energy):
nothing is created, and the ledger keeps the integrator's closure.

*Discretisation* (implicit theta-scheme of shell.kernels, step ``dt``).  With ``Q = grad V . v``
the cavity's volume rate (``Q < 0`` on outflow, ``u_j = -Q/A``), the step's over-pressure impulse
per unit area is ``j = kappa min(Q_end - min(Q_start, 0), 0)`` (taken only when ``Q_end < 0``;
``kappa = m_d / A^2`` with the outlet area at the step's start), added to the shell's residual
as ``j grad V`` (a uniform cavity pressure ``p_ex = -j/dt``) and to the vehicle's as the thrust
``-A j/dt``.  ``min(Q_start, 0)``: the inflow's stopping is not the ring's start.

*Cache.*  shell.kernels compiles these njit functions into its own cached kernels, and numba
invalidates a cache entry when the caller's file changes, not this one: after changing the code
here, clear ``pulsejet_sim/models/shell/__pycache__/kernels*.nb[ic]`` (as lumped.kernels says of
core.model_io).
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

#: the added mass of a circular disc moving broadside, over rho R^3 (Krueger 2005's model of the
#: exit over-pressure's impulse, (8/3) rho R^3 u)
DISC_ADDED_MASS_FACTOR = 8.0 / 3.0
#: the formation number: the stroke ratio L/D at which the leading ring pinches off (Gharib,
#: Rambod & Shariff 1998: 3.6 to 4.5 over their velocity programs, "about 4")
FORMATION_NUMBER = 4.0
#: formation numbers a scene may set: Gharib et al.'s range widened to what other programs report
FORMATION_NUMBER_RANGE = (0.5, 20.0)


@njit(cache=True, nogil=True)
def ring_added_mass_kg(rho, area_m2):
    """Return the added mass ``(8/3) rho R^3`` of the disc of the outlet's radius, kg."""
    radius = math.sqrt(area_m2 / math.pi)
    return DISC_ADDED_MASS_FACTOR * rho * radius * radius * radius


@njit(cache=True, nogil=True)
def ring_inertance(rho, area_m2):
    """Return ``kappa = m_d / A^2``, kg/m^4: over-pressure per unit volume acceleration."""
    return ring_added_mass_kg(rho, area_m2) / (area_m2 * area_m2)


@njit(cache=True, nogil=True)
def nozzle_diameter_m(area_m2):
    """Return the diameter of the circular outlet of area ``area_m2``, m."""
    return 2.0 * math.sqrt(area_m2 / math.pi)


@njit(cache=True, nogil=True)
def forming(formation_time, formation_number):
    """Return whether the leading ring still forms at the step's start (before pinch-off)."""
    return formation_time < formation_number


@njit(cache=True, nogil=True)
def overpressure_impulse(kappa, q_start, q_end):
    """
    Return the step's over-pressure impulse per unit area ``j`` (Pa s, <= 0); kappa > 0: forming.

    ``q_start``, ``q_end``: the cavity's volume rate at the step's start and end, m^3/s
    (negative on outflow).  ``p_ex = -j/dt`` on the wall, ``-A j/dt`` added to the thrust.
    """
    if q_end >= 0.0:
        return 0.0
    return kappa * min(q_end - min(q_start, 0.0), 0.0)


@njit(cache=True, nogil=True)
def next_formation_time(formation_time, q_mid, area_m2, dt):
    """
    Return the formation time after a step whose mean volume rate is ``q_mid`` (m^3/s).

    ``T* + u_j dt / D`` while water leaves (``q_mid < 0``); 0 when the outflow stops (the next
    outflow starts a new ring).
    """
    if q_mid >= 0.0:
        return 0.0
    return formation_time + (-q_mid / area_m2) * dt / nozzle_diameter_m(area_m2)


@njit(cache=True, nogil=True)
def piston_impulses(u_j, dt, diameter_m, rho, formation_number):
    """
    Drive the term with a prescribed jet speed through a fixed nozzle (a piston-cylinder).

    ``u_j[k]`` the jet speed at ``t = k dt`` (m/s, >= 0).  Returns (slug impulse rho A int u^2 dt,
    over-pressure impulse int A p_ex dt, stroke ratio L/D = int u dt / D, over-pressure work
    int A p_ex u dt), by the same step functions the shell kernel calls, with midpoint speeds.
    """
    area = math.pi * 0.25 * diameter_m * diameter_m
    kappa = ring_inertance(rho, area)
    i_slug = 0.0
    i_over = 0.0
    stroke = 0.0
    work = 0.0
    t_form = 0.0
    for k in range(u_j.size - 1):
        q0 = -area * u_j[k]
        q1 = -area * u_j[k + 1]
        um = 0.5 * (u_j[k] + u_j[k + 1])
        j = 0.0
        if forming(t_form, formation_number):
            j = overpressure_impulse(kappa, q0, q1)
        i_over += -area * j
        work += -area * j * um
        i_slug += rho * area * um * um * dt
        stroke += um * dt
        t_form = next_formation_time(t_form, -area * um, area, dt)
    return i_slug, i_over, stroke / diameter_m, work


def trapezoid_program(stroke_ratio, diameter_m, peak_m_s, ramp_s, dt):
    """
    Return the jet speed samples, m/s, of a trapezoidal piston program (ramp, plateau, ramp).

    The plateau's length makes the stroke ``L = stroke_ratio D``; a stroke too short for the two
    ramps is a triangle of the same ramp rate and a lower peak.
    """
    stroke = stroke_ratio * diameter_m
    if peak_m_s * ramp_s >= stroke:
        # triangle: u_max^2 / a = L with the ramp rate a = peak / ramp
        rate = peak_m_s / ramp_s
        peak = math.sqrt(stroke * rate)
        ramp = peak / rate
        plateau = 0.0
    else:
        peak, ramp = peak_m_s, ramp_s
        plateau = (stroke - peak * ramp) / peak
    total = 2.0 * ramp + plateau
    n = int(math.ceil(total / dt)) + 2
    t = np.arange(n) * dt
    u = np.where(
        t < ramp, peak * t / ramp,
        np.where(t < ramp + plateau, peak, np.maximum(peak * (total - t) / ramp, 0.0)),
    )
    return u
