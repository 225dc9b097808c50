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
mantle refills).  Once ``T*`` reaches ``F`` (the formation number, 4 by default, Gharib et al.
1998) there is no over-pressure: the ring has pinched off and the trailing jet is quasi-steady.
The step in which ``T*`` crosses ``F`` books the outflow's rise up to the crossing only (its share
of the step, ``T*`` growing linearly within it, at the previous step's rate), so the impulse and
the trajectory converge at the integrator's order where ``F`` binds.

*Energy.*  The over-pressure acts on the cavity wall (the cavity pressure rises by ``p_ex``, so
the wall and the actuator pay), and ``A p_ex`` is added to the thrust on the vehicle.  The work
that leaves the shell-vehicle system, ``A p_ex (u_j - U)`` (the exit pressure's work on the water
that crosses the exit, in the earth frame), is booked as jet output (the ring's kinetic energy):
nothing is created, and the ledger keeps the integrator's closure.

*Discretisation* (implicit theta-scheme of shell.kernels, step ``dt``).  With ``Q = grad V . v``
the cavity's volume rate (``Q < 0`` on outflow, ``u_j = -Q/A``), the step's over-pressure impulse
per unit area is ``j = kappa min(Q_end - min(Q_peak, 0), 0)`` (taken only when ``Q_end < 0``
and ``T* < F`` at the step's start; ``kappa = m_d / A^2`` with the outlet area at the step's
start), added to the shell's residual as ``j grad V`` (a uniform cavity pressure
``p_ex = -j/dt``) and to the vehicle's as the thrust ``-A j/dt``.  ``Q_peak`` is the pulse's
running peak outflow (the most negative ``Q_end`` of its steps so far, a state slot updated at
the step's end and reset with ``T*``): only an outflow beyond the pulse's previous peak is
booked, so a rippled pulse books ``m_d u_peak`` once; and an inflow's stopping is not a ring's
start.  The step predicted to cross ``T* = F`` (``crosses_formation_number``) books instead
``j = kappa s r_prev``: ``s`` the share of the step before the crossing (``pinch_off_share``),
``r_prev`` the previous step's booked rise (a state slot), see ``step_overpressure_impulse``.

*Cache.*  shell.kernels compiles these njit functions into its own cached kernels, and numba
invalidates a cache entry when the caller's file changes, not this one; shell.kernels therefore
drops its cache when this file changes (core.kernel_cache).
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
def overpressure_impulse(kappa, q_peak, q_end):
    """
    Return the step's over-pressure impulse per unit area ``j`` (Pa s, <= 0); kappa > 0: forming.

    ``q_peak``: the pulse's running peak outflow before the step (the most negative volume rate
    at the ends of the pulse's previous steps, m^3/s; 0 at a pulse's start); ``q_end``: the
    cavity's volume rate at the step's end, m^3/s (negative on outflow).  Only an outflow beyond
    the pulse's previous peak is booked, so a pulse books ``m_d u_peak`` whatever its ripple.
    ``p_ex = -j/dt`` on the wall, ``-A j/dt`` added to the thrust.
    """
    if q_end >= 0.0:
        return 0.0
    return kappa * min(q_end - min(q_peak, 0.0), 0.0)


@njit(cache=True, nogil=True)
def crosses_formation_number(formation_time, q_start, area_m2, dt, formation_number):
    """
    Return whether the step is predicted to carry T* past ``formation_number`` (pinch-off in it).

    From the step's start: ``T* + u_j dt / D >= F`` with the jet speed ``-q_start / A`` at the
    step's start (``q_start`` m^3/s, negative on outflow).  The prediction does not depend on the
    step's unknowns, so the implicit step keeps one form of the over-pressure while it iterates.
    """
    if q_start >= 0.0:
        return False
    return formation_time + (-q_start / area_m2) * dt / nozzle_diameter_m(area_m2) >= (
        formation_number
    )


@njit(cache=True, nogil=True)
def pinch_off_share(formation_time, q_mid, area_m2, dt, formation_number):
    """
    Return the share of the step before the formation time reaches ``formation_number`` (0 to 1).

    ``formation_time``: T* at the step's start (< F while the ring forms); its increment over the
    step is ``u_j dt / D`` from the mean volume rate ``q_mid`` (m^3/s), as in
    ``next_formation_time``.  T* grows linearly within the step, so pinch-off comes at the share
    ``(F - T*) / increment`` of it.  1 when the step ends before pinch-off (or water does not
    leave: T* does not grow).
    """
    rest = formation_number - formation_time
    if rest <= 0.0:
        return 0.0
    if q_mid >= 0.0:
        return 1.0
    increment = (-q_mid / area_m2) * dt / nozzle_diameter_m(area_m2)
    if increment <= rest:
        return 1.0
    return rest / increment


@njit(cache=True, nogil=True)
def step_overpressure_impulse(kappa, q_peak, q_end, crossing, share, last_rise):
    """
    Return a forming step's over-pressure impulse per unit area ``j`` (Pa s, <= 0).

    A step that does not reach pinch-off books the outflow beyond the pulse's peak,
    ``overpressure_impulse(kappa, q_peak, q_end)``: implicit, the ring's inertia.  The step in
    which T* reaches F (``crossing``) books only the rise up to pinch-off, ``share`` of the step at
    the rate of the previous step's booked rise ``last_rise`` (m^3/s, <= 0): once the ring's
    inertia is gone the outflow accelerates faster (the jet has less water to push), so the
    step's own rise ``q_end - q_peak`` is not the rate before pinch-off, and scaling it by the
    share would leave an error of first order in dt.  The previous step's rate is the rate
    before pinch-off to first order, so the crossing step's impulse is right to second order and
    the trajectory keeps the integrator's order (docs/theory/starting_jet.md).
    """
    if crossing:
        return kappa * share * last_rise
    return overpressure_impulse(kappa, q_peak, q_end)


@njit(cache=True, nogil=True)
def next_peak_outflow(q_peak, q_mid, q_end, q_booked):
    """
    Return the pulse's running peak outflow after a step (m^3/s, <= 0), reset with T*.

    While water leaves (``q_mid < 0``) the peak is the most negative end-of-step volume rate so
    far, ``min(q_peak, q_end)``.  When the outflow stops (``q_mid >= 0``: T* restarts) the next
    pulse starts from what this step booked of its outflow, ``q_booked = j / kappa`` before the
    crossing's share (<= 0; 0 where nothing was booked), so a pulse books its peak once.  Past
    pinch-off the peak books nothing until the reset: callers pass ``q_end = 0`` there.
    """
    if q_mid >= 0.0:
        return q_booked
    return min(q_peak, q_end)


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
    int A p_ex u dt), by the same step functions the shell kernel calls, with midpoint speeds:
    the pulse's running peak, and the pinch-off rule of the step that crosses ``T* = F``.
    """
    area = math.pi * 0.25 * diameter_m * diameter_m
    kappa = ring_inertance(rho, area)
    i_slug = 0.0
    i_over = 0.0
    stroke = 0.0
    work = 0.0
    t_form = 0.0
    q_peak = 0.0
    last_rise = 0.0
    for k in range(u_j.size - 1):
        q0 = -area * u_j[k]
        q1 = -area * u_j[k + 1]
        um = 0.5 * (u_j[k] + u_j[k + 1])
        qm = -area * um
        j = 0.0
        rise = 0.0
        q_end_kept = 0.0  # past pinch-off the peak is kept (it books nothing until the reset)
        if forming(t_form, formation_number):
            rise = overpressure_impulse(1.0, q_peak, q1)
            j = step_overpressure_impulse(
                kappa, q_peak, q1,
                crosses_formation_number(t_form, q0, area, dt, formation_number),
                pinch_off_share(t_form, qm, area, dt, formation_number), last_rise,
            )
            q_end_kept = q1
        i_over += -area * j
        work += -area * j * um
        i_slug += rho * area * um * um * dt
        stroke += um * dt
        q_peak = next_peak_outflow(q_peak, qm, q_end_kept, rise)
        last_rise = rise
        t_form = next_formation_time(t_form, qm, area, dt)
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
