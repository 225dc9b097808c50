"""
numba kernels of the lumped pulsed-jet model (paper 001, section 3).

Vehicle axial motion and the minor semi-axis ``b`` of an ellipsoidal shell, with the pump and the
stern valve as inputs.

Equations (see ``docs/theory/lumped.md`` for the derivation, the citations and the energy ledger).
Coupling ``consistent`` (the default, energy-consistent)::

    vehicle:  (M + m_f + m_x) U' = T - D - m_x' U - rho Q_in U
    shell:    (I_b + m_b + m_l) b'' = -k (b - b0) + R_x + V_b dp_n + Lambda V_b (Q_p' - c_a b'^2)

Coupling ``paper`` (eqs. 1 and 3 of paper 001 as written)::

    vehicle:  (M + m_f + m_x) U' = T - D - m_x' U
    shell:    (I_b + m_b + m_l) b'' = -k (b - b0) - k_x b + V_b (dp_visc + dp_valve)
                                      + Lambda V_b Q_p'

with ``V_b = dV/db = 8/3 pi a b``, the nozzle flow ``Q_n = Q_p - V_b b'`` (continuity, positive
out), the nozzle inertance ``Lambda = rho L_n / A_n`` (so ``m_l = Lambda V_b^2``, the paper's eq.
8), the pressure drop across the nozzle ``dp_n = dp_visc + dp_valve + dp_jet`` (laminar friction
and inlet loss, i.e. the paper's ``c b'``; valve loss; the Bernoulli pressure that accelerates the
jet), the outer flow's pull ``R_x = 1/2 dm_x/db U^2`` and the paper's fluid stiffness ``k_x``
(section 3.5, eq. 10). ``k (b - b0)`` is the linear spring of the paper; with ``O_HYPERELASTIC``
it is ``dU/db`` of a rubber membrane's strain energy ``U(b)`` (``shell_elastic``,
``docs/theory/hyperelastic.md``), and the elastic energy in the ledger is that ``U``.

The energy ledger books what the paper's equations create, each as the power of the difference
between the applied and the energy-consistent generalised force (``Y_C_*``): the closure
``stored - in + out - created`` then vanishes to the integrator's order in both couplings.

Physical terms are bits of an integer ``flags`` that reaches the step loop through
``numba.literally``: numba compiles (and caches) one specialisation per term set and LLVM removes
the branches of the terms that are off, so a term that is off costs nothing.

State vector ``y`` (float64): see the ``Y_*`` indices. The energy ledger integrals are state
components, integrated by the same Runge-Kutta scheme as the motion, so the closure error of the
ledger measures the integration error alone.
"""

from __future__ import annotations

import math

from numba import literally, njit
import numpy as np
from pulsejet_sim.core import model_io
from pulsejet_sim.core.kernel_cache import drop_stale_cache
from pulsejet_sim.core.model_io import VALVE_MIN_OPENING

# the valve's seat: its opening is 0 or in [VALVE_SEAT, 1] (core.model_io says why). Written out
# here as well and checked against core.model_io's, so the value numba freezes into the cached
# kernels is visible in this file (drop_stale_cache below also drops the cache when model_io.py
# changes)
VALVE_SEAT = 1.5e-3
if VALVE_SEAT != VALVE_MIN_OPENING:
    raise ImportError(
        f'lumped.kernels.VALVE_SEAT={VALVE_SEAT} differs from model_io.VALVE_MIN_OPENING='
        f'{VALVE_MIN_OPENING}; allowed: the same value (change both)'
    )

# ---- term bits --------------------------------------------------------------------------------
# Every compiled (not inlined) kernel here says fastmath=False. numba compiles a callee with the
# fastmath flags of its first caller unless the callee sets them, and keeps that one version per
# signature for every caller, on-disk cache included: lumped.batch's fast path (FAST_MATH) calls
# _advance, and the single-robot runs could otherwise inherit its rewrites and stop being
# bit-exact (found by review: the exact batch kernel did, after the fast one had compiled).
T_SHELL_INERTIA = 1 << 0
T_INTERNAL_ADDED_MASS = 1 << 1
T_NOZZLE_INERTIA = 1 << 2
T_VISCOUS_LOSS = 1 << 3
T_FLUID_STIFFNESS = 1 << 4
T_ADDED_MASS = 1 << 5
T_ADDED_MASS_VARIATION = 1 << 6
T_FLUID_MASS = 1 << 7
T_DRAG = 1 << 8
T_JET_THRUST = 1 << 9
# model options (also bits, so they are compiled in the same way)
O_COUPLING_CONSISTENT = 1 << 16  # the shell pays for the jet: Bernoulli back pressure etc.
O_ADDED_MASS_SIMPLIFIED = 1 << 17  # m_x = C_1 rho 4/3 pi b^3 instead of Lamb's exact spheroid
# the nozzle's section follows the shell, A_n = pi r_n^2 (b/b0)^2 (reading G of paper 001's eq. 8,
# whose A(x_e) is the ellipsoid's own section at the nozzle inlet plane, pi b^2 (1 - x_e^2))
O_NOZZLE_FOLLOWS_SHELL = 1 << 18
# the shell's elastic force is -dU/db of an incompressible Mooney-Rivlin (neo-Hookean: C2 = 0)
# membrane on the rest ellipsoid instead of the linear spring k (b - b0)
# (docs/theory/hyperelastic.md)
O_HYPERELASTIC = 1 << 19

# ---- state indices ----------------------------------------------------------------------------
Y_X = 0  # vehicle position, m
Y_U = 1  # vehicle velocity, m/s
Y_B = 2  # minor semi-axis, m
Y_W = 3  # db/dt, m/s
Y_QP = 4  # actual pump flow, m^3/s (first-order lag behind the command)
Y_W_PUMP = 5  # ledger integrals, J
Y_E_JET = 6
Y_E_DRAG = 7
Y_E_VISC = 8
Y_E_VALVE = 9  # valve throttling loss plus the loss when the valve seals a moving flow
Y_E_MIX = 10  # kinetic energy given to water drawn in (pump and nozzle inflow), then mixed
# energy created by the applied equations beyond the energy-consistent ones (negative: destroyed),
# J; each is int (applied - consistent generalised force) x its velocity dt
Y_C_KX = 11  # the paper's k_x b: no reaction anywhere
Y_C_JET = 12  # the Bernoulli pressure that the paper's shell does not pay for the jet
Y_C_NOZZLE = 13  # the convective term 1/2 dm_l/db b'^2 of the b-dependent nozzle mass
Y_C_AMV = 14  # the outer flow's pull R_x that pays for d(1/2 m_x U^2)/dt
Y_C_RAM = 15  # the momentum of water drawn in at rest (rho Q_in U)
Y_VALVE = 16  # actual valve opening 0..1 (rate limited, piecewise constant over a step)
NY = 17
N_INTEGRATED = 16  # components 0..15 go through Runge-Kutta

# ---- parameter indices ------------------------------------------------------------------------
P_RHO = 0  # water density, kg/m^3
P_MU = 1  # water dynamic viscosity, Pa s
P_A = 2  # major semi-axis a, m
P_B0 = 3  # rest minor semi-axis b0, m
P_K = 4  # lumped shell stiffness, N/m
P_M_SOLID = 5  # shell + payload mass, kg
P_I_B = 6  # shell wall inertia of the b mode, kg
P_M_B = 7  # internal added mass of the b mode, kg
P_L_N = 8  # nozzle length, m
P_A_N = 9  # nozzle section, m^2
P_D_N = 10  # nozzle diameter, m
P_K_INLET = 11  # square-edged inlet loss coefficient
P_CD = 12  # drag coefficient
P_V_SOLID = 13  # volume inside the shell not filled by water, m^3
P_C1 = 14  # coefficient of the simplified added mass
P_PUMP_TAU = 15  # pump spin-up time constant, s
P_VALVE_RATE = 16  # valve stroke rate, 1/s
P_B_MIN = 17  # bounds of b that the model accepts, m
P_B_MAX = 18
P_U_MAX = 19  # bound of |U|, m/s
P_P_RELIEF = 20  # pump relief valve: full flow up to this shell pressure, Pa
P_P_STALL = 21  # ... and none at this one (the pump's pressure-flow curve), Pa
P_NOZZLE_SECTION = 22  # A_n / b^2 when the nozzle follows the shell (pi r_n^2 / b0^2), 1
# the hyperelastic membrane (O_HYPERELASTIC): W = C1 (I1 - 3) + C2 (I2 - 3), Pa, and its thickness
# at rest, m. P_K then holds the membrane's tangent stiffness d2U/db2 at b0 (reports only: k_x/k)
P_MR_C1 = 23
P_MR_C2 = 24
P_MEMBRANE_THICKNESS = 25
NP = 26

# ---- diagnostic outputs of the right-hand side --------------------------------------------------
D_THRUST = 0
D_AMV_FORCE = 1
D_DRAG = 2
D_Q_N = 3
D_P_CAV = 4
D_ACCEL = 5
D_M_X = 6
D_K_X = 7  # the paper's fluid stiffness k_x (eq. 10), N/m, in both couplings
D_M_L = 8
D_VEHICLE_MASS = 9
D_B_MASS = 10
D_DAMPING_RATE = 11  # estimate of the fastest decay rate, 1/s (sets the sub-steps)
D_SPRING_RATE = 12  # shell angular frequency sqrt(k_eff/m), rad/s
D_A_N = 13  # nozzle section, m^2
ND = 14

# status codes of advance()
OK = 0
ERR_NONFINITE = 1
ERR_B_LOW = 2
ERR_B_HIGH = 3
ERR_SPEED = 4
ERR_SUBSTEPS = 5

RK4_STABLE_REAL = 2.785  # RK4 stability limit on the negative real axis
MAX_SUBSTEPS = 4096


@njit(cache=True, nogil=True, inline='always')
def added_mass(flags, b, p):
    """Axial added mass m_x(b) and dm_x/db of the prolate spheroid (kg, kg/m)."""
    rho = p[P_RHO]
    a = p[P_A]
    if flags & O_ADDED_MASS_SIMPLIFIED:
        c = p[P_C1] * rho * 4.0 / 3.0 * math.pi
        return c * b**3, 3.0 * c * b**2
    # Lamb's exact potential-flow coefficient k1 = alpha0 / (2 - alpha0)
    ratio = b / a
    e2 = 1.0 - ratio * ratio
    e = math.sqrt(e2)
    g = math.atanh(e) - e
    alpha0 = 2.0 * (1.0 - e2) / (e2 * e) * g
    dalpha_de = 2.0 * g * (-2.0 / e2 - 3.0 * (1.0 - e2) / (e2 * e2)) + 2.0 / e
    de_db = -b / (a * a * e)
    k1 = alpha0 / (2.0 - alpha0)
    dk1_db = 2.0 / (2.0 - alpha0) ** 2 * dalpha_de * de_db
    vol_coef = rho * 4.0 / 3.0 * math.pi * a
    return k1 * vol_coef * b * b, vol_coef * (dk1_db * b * b + 2.0 * k1 * b)


@njit(cache=True, nogil=True, inline='always')
def fluid_stiffness_force(b, u, p):
    """
    Return the paper's fluid stiffness (section 3.5, eqs. 9-10; eq. 10 lost).

    U_max/U = 1 + b/2a, Cp = 1 - (U_max/U)^2, dCp = -2 Cp (the internal coefficient Cp' not given:
    0), integral force F = q 2 pi a b dCp with q = rho U^2 / 2, and dF = k_x db. Returns (F in N,
    k_x in N/m); the paper coupling applies k_x b (eq. 3), the consistent one only reports k_x.
    """
    a = p[P_A]
    q = 0.5 * p[P_RHO] * u * u
    s = 1.0 + b / (2.0 * a)
    dcp = 2.0 * (s * s - 1.0)
    ddcp_db = 2.0 * s / a
    force = q * 2.0 * math.pi * a * b * dcp
    k_x = q * 2.0 * math.pi * a * (dcp + b * ddcp_db)
    return force, k_x


# ---- hyperelastic membrane shell (docs/theory/hyperelastic.md) ---------------------------------
# Gauss-Legendre nodes in the reference meridian angle theta in (0, pi/2) (the half from the
# equator to a pole; the spheroid is symmetric about its equator). On the escape scenes' ellipsoid
# (a = 5 b0) 24 nodes integrate the membrane energy to < 1e-11 relative for b >= 0.7 b0, 5e-9 at
# b0/3 (test_lumped_hyperelastic) and 2e-3 at the collapse bound 0.02 b0, where a squeezed
# membrane's energy gathers at the poles; the force is the derivative of this sum, so the ledger
# closes whatever the quadrature's error.
MEMBRANE_NODES = 24
_GL_X, _GL_W = np.polynomial.legendre.leggauss(MEMBRANE_NODES)
MEMBRANE_SIN = np.sin(np.pi / 4.0 * (_GL_X + 1.0))
MEMBRANE_COS = np.cos(np.pi / 4.0 * (_GL_X + 1.0))
MEMBRANE_WEIGHT = np.pi / 4.0 * _GL_W


@njit(cache=True, nogil=True, fastmath=False)
def membrane_spheroid(a0, b0, a, b, c1, c2, thickness):
    """
    Return the strain energy of a spheroidal membrane and its derivatives (J, N, N, N/m).

    The reference spheroid (semi-axes a0 along the axis, b0 across) is mapped to the spheroid
    (a, b) point by point: the material point at meridian angle theta, (a0 cos, b0 sin), goes to
    (a cos, b sin). Principal stretches: hoop h = b/b0 (the same everywhere), meridian
    m = sqrt(a^2 sin^2 + b^2 cos^2) / sqrt(a0^2 sin^2 + b0^2 cos^2); thickness stretch 1/(h m)
    (incompressible). W = C1 (I1 - 3) + C2 (I2 - 3) per unit reference volume with
    I1 = h^2 + m^2 + 1/(h m)^2, I2 = 1/h^2 + 1/m^2 + (h m)^2 (neo-Hookean: C2 = 0, mu = 2 C1).
    U = thickness * int W dA0 by Gauss-Legendre in theta. Returns (U, dU/da, dU/db, d2U/db2):
    the derivatives are those of the quadrature sum itself, so -dU/db is exactly the force whose
    work changes U.
    """
    energy = 0.0
    du_da = 0.0
    du_db = 0.0
    d2u_db2 = 0.0
    h = b / b0
    h2 = h * h
    for i in range(MEMBRANE_NODES):
        s = MEMBRANE_SIN[i]
        c = MEMBRANE_COS[i]
        s0 = math.sqrt(a0 * a0 * s * s + b0 * b0 * c * c)
        sc = math.sqrt(a * a * s * s + b * b * c * c)
        m = sc / s0
        m2 = m * m
        dm_db = b * c * c / (sc * s0)
        dm_da = a * s * s / (sc * s0)
        d2m_db2 = a * a * s * s * c * c / (sc * sc * sc * s0)
        inv = 1.0 / (h2 * m2)  # the thickness stretch squared
        w = c1 * (h2 + m2 + inv - 3.0) + c2 * (1.0 / h2 + 1.0 / m2 + h2 * m2 - 3.0)
        w_h = c1 * (2.0 * h - 2.0 * inv / h) + c2 * (-2.0 / (h2 * h) + 2.0 * h * m2)
        w_m = c1 * (2.0 * m - 2.0 * inv / m) + c2 * (-2.0 / (m2 * m) + 2.0 * h2 * m)
        w_hh = c1 * (2.0 + 6.0 * inv / h2) + c2 * (6.0 / (h2 * h2) + 2.0 * m2)
        w_mm = c1 * (2.0 + 6.0 * inv / m2) + c2 * (6.0 / (m2 * m2) + 2.0 * h2)
        w_hm = c1 * 4.0 * inv / (h * m) + c2 * 4.0 * h * m
        area = MEMBRANE_WEIGHT[i] * 2.0 * math.pi * b0 * s * s0  # reference area per dtheta
        energy += area * w
        du_da += area * w_m * dm_da
        du_db += area * (w_h / b0 + w_m * dm_db)
        d2u_db2 += area * (
            w_hh / (b0 * b0) + 2.0 * w_hm * dm_db / b0 + w_mm * dm_db * dm_db + w_m * d2m_db2
        )
    scale = 2.0 * thickness  # both halves of the spheroid
    return scale * energy, scale * du_da, scale * du_db, scale * d2u_db2


@njit(cache=True, nogil=True, inline='always')
def shell_elastic(flags, b, p):
    """
    Return the shell's elastic energy U (J), its force dU/db (N) and stiffness d2U/db2 (N/m).

    Linear spring (the default): U = 1/2 k (b - b0)^2. With O_HYPERELASTIC: the membrane of
    membrane_spheroid on the rest ellipsoid (a, b0), deformed at fixed length to (a, b).
    """
    if flags & O_HYPERELASTIC:
        energy, _, force, stiffness = membrane_spheroid(
            p[P_A], p[P_B0], p[P_A], b, p[P_MR_C1], p[P_MR_C2], p[P_MEMBRANE_THICKNESS]
        )
        return energy, force, stiffness
    return 0.5 * p[P_K] * (b - p[P_B0]) ** 2, p[P_K] * (b - p[P_B0]), p[P_K]


@njit(cache=True, nogil=True, inline='always')
def shell_inertia(flags, p):
    """
    Return the b mode's mass without the nozzle water, I_b + m_b (kg), and a rigid nozzle's Lambda.

    Lambda = rho L_n / A_n is the nozzle inertance (m_l = Lambda V_b^2 is added where the flow
    decides it); each is 0 when its term is off.
    """
    m_shell = 0.0
    if flags & T_SHELL_INERTIA:
        m_shell += p[P_I_B]
    if flags & T_INTERNAL_ADDED_MASS:
        m_shell += p[P_M_B]
    inertance = 0.0
    if flags & T_NOZZLE_INERTIA:
        inertance = p[P_RHO] * p[P_L_N] / p[P_A_N]
    return m_shell, inertance


@njit(cache=True, nogil=True, inline='always')
def nozzle(flags, b, p):
    """
    Return the nozzle's section A_n (m^2), diameter (m), inertance Lambda and dLambda/db.

    Rigid (the default): A_n = pi r_n^2. With O_NOZZLE_FOLLOWS_SHELL, A_n = pi r_n^2 (b/b0)^2, so
    Lambda = rho L_n / A_n falls as 1/b^2 and m_l = Lambda V_b^2 is a constant (reading G,
    docs/theory/lumped.md). Lambda and its derivative are 0 when the nozzle_inertia term is off.
    """
    if flags & O_NOZZLE_FOLLOWS_SHELL:
        a_n = p[P_NOZZLE_SECTION] * b * b
        d_n = 2.0 * math.sqrt(a_n / math.pi)
    else:
        a_n = p[P_A_N]
        d_n = p[P_D_N]
    inertance = 0.0
    dinertance_db = 0.0
    if flags & T_NOZZLE_INERTIA:
        inertance = p[P_RHO] * p[P_L_N] / a_n
        if flags & O_NOZZLE_FOLLOWS_SHELL:
            dinertance_db = -2.0 * inertance / b
    return a_n, d_n, inertance, dinertance_db


@njit(cache=True, nogil=True, inline='always')
def pump_flow_rate(q_cmd, q_p, f_el, v_b, p):
    """
    Return dq_p/dt of the pump's first-order spin-up towards its pressure-limited flow.

    The pump's pressure-flow curve (a positive-displacement pump with a relief valve): full flow
    up to the relief pressure of the shell's elastic pressure f_el / V_b, none at the stall
    pressure, linear between; it keeps any command sequence from inflating the shell past its
    bound.
    """
    q_target = q_cmd
    if q_cmd > 0.0:
        p_el = f_el / v_b
        if p_el > p[P_P_RELIEF]:
            q_target = q_cmd * max(0.0, (p[P_P_STALL] - p_el) / (p[P_P_STALL] - p[P_P_RELIEF]))
    return (q_target - q_p) / p[P_PUMP_TAU]


@njit(cache=True, nogil=True, inline='always')
def outer_flow(flags, b, u, p):
    """
    Return the outer water's (m_x, dm_x/db, k_x, k_x b applied, R_x reference, R_x applied).

    Added mass m_x (Lamb's or the simplified form); the paper's fluid stiffness k_x (section 3.5,
    eq. 10), applied as k_x b in eq. 3 by the paper coupling and a reported diagnostic only in the
    consistent one; the outer flow's pull on the shell that pays for d(1/2 m_x U^2)/dt,
    R_x = 1/2 dm_x/db U^2, applied by the consistent coupling.
    """
    m_x = 0.0
    dmx_db = 0.0
    if flags & (T_ADDED_MASS | T_ADDED_MASS_VARIATION):
        m_x, dmx_db = added_mass(flags, b, p)
    k_x = 0.0
    f_kx = 0.0
    if flags & T_FLUID_STIFFNESS:
        _, k_x = fluid_stiffness_force(b, u, p)
        if not flags & O_COUPLING_CONSISTENT:
            f_kx = k_x * b
    reaction_ref = 0.0
    if flags & T_ADDED_MASS_VARIATION:
        reaction_ref = 0.5 * dmx_db * u * u
    reaction = 0.0
    if flags & O_COUPLING_CONSISTENT:
        if flags & T_FLUID_STIFFNESS:
            reaction = reaction_ref
    return m_x, dmx_db, k_x, f_kx, reaction_ref, reaction


@njit(cache=True, nogil=True, inline='always')
def open_cavity(
    flags, valve, w, q_p, dq_p, c_a, v_b, a_n, d_n, inertance, dinertance_db, m_shell, m_l,
    load, p,
):
    """
    Return the open cavity's nozzle flow and the shell's b acceleration.

    load: the shell's elastic, fluid-stiffness and outer-flow force on b (-f_el - f_kx + R_x).
    Returns (q_n, dw, p_cav, dp_visc, dp_valve, dp_jet_ref, m_b_total, damping_rate, c_jet,
    c_nozzle): nozzle flow, b acceleration, cavity pressure at the nozzle inlet, the three
    pressure drops (viscous, valve, Bernoulli), the b mode's mass with the nozzle water, the
    flow's damping rate of b, and the paper coupling's created powers of the jet and nozzle.
    """
    rho = p[P_RHO]
    c_jet = 0.0
    c_nozzle = 0.0
    q_n = q_p - v_b * w
    u_n = q_n / a_n
    sgn = 1.0 if u_n >= 0.0 else -1.0
    dp_visc = 0.0
    dpdq = 0.0
    if flags & T_VISCOUS_LOSS:
        # the paper's c b' (section 3.3): Darcy's laminar f = 64/Re along the nozzle plus a
        # square-edged inlet coefficient, dp = 1/2 rho (f L/d + K) u_n^2
        lam = 32.0 * p[P_MU] * p[P_L_N] / (d_n * d_n)
        dp_visc = lam * u_n + sgn * 0.5 * rho * p[P_K_INLET] * u_n * u_n
        dpdq += (lam + rho * p[P_K_INLET] * abs(u_n)) / a_n
    # valve as an orifice at the nozzle inlet: Borda-Carnot loss of the contraction to
    # valve*A_n
    contraction = 1.0 / valve - 1.0
    dp_valve = sgn * 0.5 * rho * contraction * contraction * u_n * u_n
    dpdq += rho * contraction * contraction * abs(u_n) / a_n
    # Bernoulli pressure that accelerates the jet, and the convective part of the nozzle
    # inertia (m_l = Lambda V_b^2 depends on b: 1/2 dm_l/db b'^2 = Lambda V_b c_a b'^2)
    dp_jet_ref = sgn * 0.5 * rho * u_n * u_n
    dp_jet = 0.0
    convective = 0.0
    # a nozzle whose section follows the shell: Lagrange's equation of its water's kinetic
    # energy 1/2 Lambda(b) Q_n^2 has dLambda/db Q_n (V_b b' + Q_n/2) besides the terms of a
    # rigid one (with the pump off the two cancel: m_l is then a constant)
    dilation = 0.0
    if flags & O_NOZZLE_FOLLOWS_SHELL:
        dilation = dinertance_db * q_n * (v_b * w + 0.5 * q_n)
    if flags & O_COUPLING_CONSISTENT:
        dp_jet = dp_jet_ref
        dpdq += rho * abs(u_n) / a_n
        convective = c_a * w * w
    else:
        c_jet = -v_b * dp_jet_ref * w
        c_nozzle = inertance * v_b * c_a * w * w * w
        if flags & O_NOZZLE_FOLLOWS_SHELL:
            c_nozzle -= dilation * w
            dilation = 0.0
    dp_n = dp_visc + dp_valve + dp_jet
    m_b_total = m_shell + m_l
    force = load + v_b * dp_n + inertance * v_b * (dq_p - convective)
    if flags & O_NOZZLE_FOLLOWS_SHELL:
        force += dilation
    dw = force / m_b_total
    # cavity pressure at the nozzle inlet: what the nozzle flow needs (drop + acceleration);
    # the same definition in both couplings, so the pump's work is the same physical quantity
    dq_n = dq_p - c_a * w * w - v_b * dw
    p_cav = dp_visc + dp_valve + dp_jet_ref + inertance * dq_n
    if flags & O_NOZZLE_FOLLOWS_SHELL:
        p_cav += dinertance_db * w * q_n
    damping_rate = v_b * v_b * dpdq / m_b_total
    return (
        q_n, dw, p_cav, dp_visc, dp_valve, dp_jet_ref, m_b_total, damping_rate, c_jet, c_nozzle
    )


@njit(cache=True, nogil=True, inline='always')
def vehicle_forces(flags, u, b, w, q_p, q_n, a_n, volume, m_x, dmx_db, p):
    """
    Return the vehicle's mass and axial forces (kg, N, m^3/s; forward +).

    (mass, thrust, drag, added-mass variation force, inflow, ram reference, ram applied). The
    mass carries the water inside (T_FLUID_MASS) and the added mass; the jet's momentum thrust
    rho Q_n^2 / A_n while water leaves; the body's quadratic drag; -dm_x/db b' U; water drawn in
    at rest must be brought to the vehicle's speed (the ram, rho Q_in U; eq. 1 has no such term,
    the consistent coupling applies it).
    """
    rho = p[P_RHO]
    m_vehicle = p[P_M_SOLID]
    if flags & T_FLUID_MASS:
        m_vehicle += rho * (volume - p[P_V_SOLID])
    if flags & T_ADDED_MASS:
        m_vehicle += m_x
    thrust = 0.0
    if flags & T_JET_THRUST:
        if q_n > 0.0:
            thrust = rho * q_n * q_n / a_n
    drag = 0.0
    if flags & T_DRAG:
        drag = 0.5 * rho * p[P_CD] * math.pi * b * b * u * abs(u)
    amv_force = 0.0
    if flags & T_ADDED_MASS_VARIATION:
        amv_force = -dmx_db * w * u
    q_in = q_p
    if q_n < 0.0:
        q_in -= q_n
    ram_ref = 0.0
    if flags & T_FLUID_MASS:
        ram_ref = rho * q_in * u
    ram = 0.0
    if flags & O_COUPLING_CONSISTENT:
        ram = ram_ref
    return m_vehicle, thrust, drag, amv_force, q_in, ram_ref, ram


@njit(cache=True, nogil=True, fastmath=False)
def rhs(flags, y, valve, q_cmd, p, dy, diag):
    """
    Time derivatives of y at fixed valve opening and pump command; fills diag.

    Every force that the energy-consistent coupling applies is computed (its ``*_ref`` value); the
    coupling decides which are applied, and the ledger books the power of the difference as
    created energy (``Y_C_*``). The stages (pump, shell, outer flow, cavity and nozzle, vehicle)
    are inlined functions: one compiled body, the same arithmetic in the same order.
    """
    rho = p[P_RHO]
    a = p[P_A]
    u = y[Y_U]
    b = y[Y_B]
    w = y[Y_W]
    q_p = y[Y_QP]
    c_a = 8.0 / 3.0 * math.pi * a
    v_b = c_a * b  # dV/db, m^2
    # the shell's elastic force dU/db and stiffness (the linear spring k (b - b0), k by default)
    _, f_el, k_el = shell_elastic(flags, b, p)
    dq_p = pump_flow_rate(q_cmd, q_p, f_el, v_b, p)
    volume = c_a * b * b / 2.0  # 4/3 pi a b^2
    a_n, d_n, inertance, dinertance_db = nozzle(flags, b, p)
    # shell inertia of the b mode (the nozzle part depends on the flow and is added below)
    m_shell, _ = shell_inertia(flags, p)
    m_l = inertance * v_b * v_b
    m_x, dmx_db, k_x, f_kx, reaction_ref, reaction = outer_flow(flags, b, u, p)

    if valve <= 0.0:
        # valve shut: incompressible water, the pump alone sets the volume rate
        q_n = 0.0
        dw = (dq_p - c_a * w * w) / v_b
        p_cav = (m_shell * dw + f_el + f_kx - reaction) / v_b
        dp_visc = 0.0
        dp_valve = 0.0
        dp_jet_ref = 0.0
        m_b_total = m_shell
        damping_rate = 0.0
        c_jet = 0.0
        c_nozzle = 0.0
    else:
        (q_n, dw, p_cav, dp_visc, dp_valve, dp_jet_ref, m_b_total, damping_rate, c_jet,
         c_nozzle) = open_cavity(
            flags, valve, w, q_p, dq_p, c_a, v_b, a_n, d_n, inertance, dinertance_db, m_shell,
            m_l, -f_el - f_kx + reaction, p,
        )
    spring = k_el
    if not flags & O_COUPLING_CONSISTENT:
        spring += k_x

    m_vehicle, thrust, drag, amv_force, q_in, ram_ref, ram = vehicle_forces(
        flags, u, b, w, q_p, q_n, a_n, volume, m_x, dmx_db, p
    )
    du = (thrust - drag + amv_force - ram) / m_vehicle

    dy[Y_X] = u
    dy[Y_U] = du
    dy[Y_B] = w
    dy[Y_W] = dw
    dy[Y_QP] = dq_p
    # ledger rates, W
    dy[Y_W_PUMP] = p_cav * q_p
    if q_n > 0.0:
        u_j = q_n / a_n
        dy[Y_E_JET] = 0.5 * rho * q_n * (u_j - u) ** 2  # earth frame
        dy[Y_E_MIX] = 0.5 * rho * q_in * u * u
    else:
        # inflow through the nozzle: its jet into the cavity and its speed-up to U are mixed away
        dy[Y_E_JET] = 0.0
        dy[Y_E_MIX] = 0.5 * rho * q_in * u * u + q_n * dp_jet_ref
    dy[Y_E_DRAG] = drag * u
    dy[Y_E_VISC] = q_n * dp_visc
    dy[Y_E_VALVE] = q_n * dp_valve
    # created energy: (applied - energy-consistent generalised force) x velocity
    dy[Y_C_KX] = -f_kx * w
    dy[Y_C_JET] = c_jet
    dy[Y_C_NOZZLE] = c_nozzle
    dy[Y_C_AMV] = (reaction - reaction_ref) * w
    dy[Y_C_RAM] = (ram_ref - ram) * u

    diag[D_THRUST] = thrust
    diag[D_AMV_FORCE] = amv_force
    diag[D_DRAG] = -drag
    diag[D_Q_N] = q_n
    diag[D_P_CAV] = p_cav
    diag[D_ACCEL] = du
    diag[D_M_X] = m_x
    diag[D_K_X] = k_x
    diag[D_M_L] = m_l
    diag[D_VEHICLE_MASS] = m_vehicle
    diag[D_B_MASS] = m_b_total
    diag[D_DAMPING_RATE] = damping_rate
    diag[D_SPRING_RATE] = math.sqrt(abs(spring) / m_b_total) if m_b_total > 0.0 else 0.0
    diag[D_A_N] = a_n


@njit(cache=True, nogil=True, fastmath=False)
def _rk4(flags, y, valve, q_cmd, p, h, k1, k2, k3, k4, tmp, diag):
    """
    Take one classical RK4 step of size h.

    k1 must already hold rhs at y (the caller evaluated it).
    """
    n = N_INTEGRATED
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    tmp[Y_VALVE] = valve
    rhs(flags, tmp, valve, q_cmd, p, k2, diag)
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    rhs(flags, tmp, valve, q_cmd, p, k3, diag)
    for i in range(n):
        tmp[i] = y[i] + h * k3[i]
    rhs(flags, tmp, valve, q_cmd, p, k4, diag)
    for i in range(n):
        y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(cache=True, nogil=True, fastmath=False)
def _check(y, p):
    for i in range(NY):
        if not math.isfinite(y[i]):
            return ERR_NONFINITE
    if y[Y_B] <= p[P_B_MIN]:
        return ERR_B_LOW
    if y[Y_B] >= p[P_B_MAX]:
        return ERR_B_HIGH
    if abs(y[Y_U]) > p[P_U_MAX]:
        return ERR_SPEED
    return OK


@njit(cache=True, nogil=True, fastmath=False)
def stored_energy(flags, y, p):
    """Mechanical energy held by the system, J: (elastic, vehicle, outer fluid, internal)."""
    rho = p[P_RHO]
    b = y[Y_B]
    w = y[Y_W]
    u = y[Y_U]
    elastic, _, _ = shell_elastic(flags, b, p)
    m_vehicle = p[P_M_SOLID]
    if flags & T_FLUID_MASS:
        m_vehicle += rho * (4.0 / 3.0 * math.pi * p[P_A] * b * b - p[P_V_SOLID])
    m_x = 0.0
    if flags & T_ADDED_MASS:
        m_x, _ = added_mass(flags, b, p)
    m_shell, _ = shell_inertia(flags, p)
    _, _, inertance, _ = nozzle(flags, b, p)
    internal = 0.5 * m_shell * w * w
    if flags & T_NOZZLE_INERTIA:
        if y[Y_VALVE] > 0.0:
            q_n = y[Y_QP] - 8.0 / 3.0 * math.pi * p[P_A] * b * w
            internal += 0.5 * inertance * q_n * q_n
    return elastic, 0.5 * m_vehicle * u * u, 0.5 * m_x * u * u, internal


@njit(cache=True, nogil=True, fastmath=False)
def _seal(flags, y, p):
    """
    Seal a moving flow at the valve: the water in the nozzle stops, the shell follows the pump.

    An impulsive constraint: the cavity pressure impulse Pi that brings the shell from b' to the
    pump's rate b'+ = Q_p / V_b (m_s (b'+ - b') = V_b Pi, m_s the shell's b-mode mass without the
    nozzle water) is also what the pump pushes its flow against, so the pump does the work
    Pi Q_p = m_s (b'+ - b') b'+ (booked as pump work, the input that pays for it), and the valve
    takes the rest of the change, 1/2 m_s (b'+ - b')^2 + 1/2 Lambda Q_n^2 >= 0 (the nozzle water's
    kinetic energy and the shell's inelastic jump). Their sum is the change of the stored energy.
    """
    m_s, _ = shell_inertia(flags, p)
    _, _, inertance, _ = nozzle(flags, y[Y_B], p)
    v_b = 8.0 / 3.0 * math.pi * p[P_A] * y[Y_B]
    w_before = y[Y_W]
    q_n = y[Y_QP] - v_b * w_before
    w_after = y[Y_QP] / v_b
    jump = w_after - w_before
    y[Y_VALVE] = 0.0
    y[Y_W] = w_after
    y[Y_W_PUMP] += m_s * jump * w_after
    y[Y_E_VALVE] += 0.5 * m_s * jump * jump + 0.5 * inertance * q_n * q_n


@njit(cache=True, nogil=True, fastmath=False)
def _advance(flags, y, p, q_cmd, valve_cmd, n_steps, dt):
    """
    Advance y by n_steps fixed steps of dt.

    Returns (steps done, status); on a bad state y is restored to the last good step.
    """
    k1 = np.empty(NY)
    k2 = np.empty(NY)
    k3 = np.empty(NY)
    k4 = np.empty(NY)
    tmp = np.empty(NY)
    diag = np.empty(ND)
    last = y.copy()
    for step in range(n_steps):
        for i in range(NY):
            last[i] = y[i]
        valve = y[Y_VALVE]
        rhs(flags, y, valve, q_cmd, p, k1, diag)
        # Sub-steps keep RK4 inside its stability region when the valve throttles a fast flow
        # (the loss rate grows like 1/opening^2) or a light shell meets a stiff spring.
        rate = max(diag[D_DAMPING_RATE], diag[D_SPRING_RATE])
        n_sub = 1
        if rate * dt > 1.5:
            n_sub = int(math.ceil(rate * dt / 1.5))
            if n_sub > MAX_SUBSTEPS:
                return step, ERR_SUBSTEPS
        h = dt / n_sub
        for sub in range(n_sub):
            if sub > 0:  # the first k1 is the evaluation that sized the sub-steps
                rhs(flags, y, valve, q_cmd, p, k1, diag)
            _rk4(flags, y, valve, q_cmd, p, h, k1, k2, k3, k4, tmp, diag)
        # the valve moves at its stroke rate between steps
        if valve_cmd != valve:
            stroke = p[P_VALVE_RATE] * dt
            new_valve = valve_cmd
            if valve_cmd > valve + stroke:
                new_valve = valve + stroke
            elif valve_cmd < valve - stroke:
                new_valve = valve - stroke
            if 0.0 < new_valve < VALVE_SEAT:
                # it cracks open to its seat, or seals when closing would pass below it
                new_valve = VALVE_SEAT if valve_cmd > valve else 0.0
            if new_valve <= 0.0 < valve:
                _seal(flags, y, p)  # sealing a moving flow
            else:
                y[Y_VALVE] = new_valve
        status = _check(y, p)
        if status != OK:
            for i in range(NY):
                y[i] = last[i]
            return step, status
    return n_steps, OK


@njit(cache=True, nogil=True, fastmath=False)
def advance(flags, y, p, q_cmd, valve_cmd, n_steps, dt):
    """Entry point: specialise on the term set (see module docstring)."""
    return _advance(literally(flags), y, p, q_cmd, valve_cmd, n_steps, dt)


@njit(cache=True, nogil=True, fastmath=False)
def _evaluate(flags, y, p, q_cmd, diag):
    dy = np.empty(NY)
    rhs(flags, y, y[Y_VALVE], q_cmd, p, dy, diag)
    e = stored_energy(flags, y, p)
    return e[0], e[1], e[2], e[3]


@njit(cache=True, nogil=True, fastmath=False)
def evaluate(flags, y, p, q_cmd, diag):
    """Fill diag at the state y and return the stored energies (see stored_energy)."""
    return _evaluate(literally(flags), y, p, q_cmd, diag)


_SPECIALISED: dict = {}


def specialised(dispatcher, flags: int, *args):
    """
    Return the compiled entry point of `dispatcher` for this literal flag value.

    ``numba.literally`` re-dispatches through Python on every call (milliseconds); the entry point
    of the specialisation skips that, so a batch of a few physics steps stays cheap. The first call
    compiles (or loads from the on-disk cache) the specialisation.
    """
    key = (dispatcher, flags)
    fn = _SPECIALISED.get(key)
    if fn is None:
        dispatcher(flags, *args)
        for sig, cres in dispatcher.overloads.items():
            if getattr(sig[0], 'literal_value', None) == flags:
                fn = cres.entry_point
                break
        else:  # pragma: no cover - numba changed how it stores literal specialisations
            fn = dispatcher
        _SPECIALISED[key] = fn
    return fn


# ==== adaptive, error-controlled integrator ======================================================
# Dormand-Prince 5(4) (Hairer, Norsett & Wanner, Solving ODEs I, II.5; the pair of DOPRI5 and
# scipy's RK45): 7 stages, first-same-as-last, local extrapolation (the 5th-order solution is
# kept), PI step-size control (Hairer & Wanner's DOPRI5 constants, beta = 0.04), and cubic Hermite
# dense output from the end-point values and slopes (3rd order, exact at the step's ends) for
# outputs at the publication rate. Piecewise-smooth inputs are handled by integrating segments on
# which they are smooth: the caller's command is constant over a call and the valve moves linearly
# at its stroke rate until it reaches the command (a kink), so the integration stops exactly at the
# kink and the step-size controller restarts there and at every command change. A shut valve cracks
# open to its seat (VALVE_SEAT) and a closing one seals there, with the same jump (and the same
# valve-loss booking) as the fixed-step path.
DP_C2, DP_C3, DP_C4, DP_C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
DP_A21 = 1.0 / 5.0
DP_A31, DP_A32 = 3.0 / 40.0, 9.0 / 40.0
DP_A41, DP_A42, DP_A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
DP_A51, DP_A52, DP_A53, DP_A54 = (
    19372.0 / 6561.0,
    -25360.0 / 2187.0,
    64448.0 / 6561.0,
    -212.0 / 729.0,
)
DP_A61, DP_A62, DP_A63, DP_A64, DP_A65 = (
    9017.0 / 3168.0,
    -355.0 / 33.0,
    46732.0 / 5247.0,
    49.0 / 176.0,
    -5103.0 / 18656.0,
)
DP_B1, DP_B3, DP_B4, DP_B5, DP_B6 = (
    35.0 / 384.0,
    500.0 / 1113.0,
    125.0 / 192.0,
    -2187.0 / 6784.0,
    11.0 / 84.0,
)
# error coefficients: 5th-order minus 4th-order weights
DP_E1, DP_E3, DP_E4, DP_E5, DP_E6, DP_E7 = (
    71.0 / 57600.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
)
ADAPT_SAFETY = 0.9
ADAPT_FAC_MIN = 0.2
ADAPT_FAC_MAX = 10.0
ADAPT_BETA = 0.04  # PI part of the controller (0: classical I controller)
ADAPT_MAX_STEPS = 10_000_000  # per call; beyond: ERR_SUBSTEPS
ADAPT_H_MIN = 1e-12  # s; a step below it is a fault (stiffness out of range)
# step-memory slots appended to the state vector of an adaptive run (after the NY physical ones)
M_H = 0  # next step size, s (0: restart the controller)
M_ERR = 1  # previous accepted error norm (PI controller)
M_Q = 2  # command of the previous call: a change restarts the controller
M_VALVE = 3
NMEM = 4

# statistics returned by adaptive_advance
S_ACCEPTED = 0
S_REJECTED = 1
S_RHS = 2
S_T_DONE = 3  # time reached (s, from the call's start); < duration only on a fault
NSTATS = 4


@njit(cache=True, nogil=True, fastmath=False)
def _err_norm(y0, y1, e, h, rtol, atol):
    """RMS of the local error estimate h*sum(E_i k_i) scaled by atol + rtol*max(|y0|, |y1|)."""
    s = 0.0
    for i in range(N_INTEGRATED):
        sc = atol + rtol * max(abs(y0[i]), abs(y1[i]))
        r = h * e[i] / sc
        s += r * r
    return math.sqrt(s / N_INTEGRATED)


@njit(cache=True, nogil=True, fastmath=False)
def _initial_step(flags, y, f0, valve, q_cmd, p, rtol, atol, span, tmp, f1, diag):
    """
    Return Hairer, Norsett & Wanner's starting step (II.4).

    h0 from |y|/|f|, refined by one Euler probe.
    """
    d0 = 0.0
    d1 = 0.0
    for i in range(N_INTEGRATED):
        sc = atol + rtol * abs(y[i])
        d0 += (y[i] / sc) ** 2
        d1 += (f0[i] / sc) ** 2
    d0 = math.sqrt(d0 / N_INTEGRATED)
    d1 = math.sqrt(d1 / N_INTEGRATED)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, span)
    for i in range(N_INTEGRATED):
        tmp[i] = y[i] + h0 * f0[i]
    rhs(flags, tmp, valve, q_cmd, p, f1, diag)
    d2 = 0.0
    for i in range(N_INTEGRATED):
        sc = atol + rtol * abs(y[i])
        d2 += ((f1[i] - f0[i]) / sc) ** 2
    d2 = math.sqrt(d2 / N_INTEGRATED) / h0
    if max(d1, d2) <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** 0.2
    return min(100.0 * h0, h1, span)


@njit(cache=True, nogil=True, inline='always')
def _valve_at(v0, v_rate, dt):
    v = v0 + v_rate * dt
    return min(max(v, 0.0), 1.0)


@njit(cache=True, nogil=True, fastmath=False)
def _segment(
    flags,
    y,
    p,
    q_cmd,
    v0,
    v_rate,
    t0,
    t1,
    rtol,
    atol,
    mem,
    t_out,
    out,
    n_out_done,
    stats,
    ks,
    tmp,
    y_old,
    diag,
):
    """
    Integrate y from t0 to t1 with the valve at v0 + v_rate (t - t0) (a smooth segment).

    Outputs at the times t_out[j] in (t0, t1] by Hermite interpolation. Returns (status, outputs
    written, time reached).
    """
    k1 = ks[0]
    k2 = ks[1]
    k3 = ks[2]
    k4 = ks[3]
    k5 = ks[4]
    k6 = ks[5]
    k7 = ks[6]
    e = ks[7]
    j = n_out_done
    n_out = t_out.shape[0]
    t = t0
    if t1 <= t0:
        stats[S_T_DONE] = t0
        return OK, j, t0
    rhs(flags, y, v0, q_cmd, p, k1, diag)
    stats[S_RHS] += 1
    h = mem[M_H]
    if h <= 0.0:
        h = _initial_step(flags, y, k1, v0, q_cmd, p, rtol, atol, t1 - t0, tmp, k2, diag)
        stats[S_RHS] += 1
        mem[M_ERR] = 1e-4
    steps = 0
    while t < t1:
        last = False
        if t + h >= t1 - (1e-9 + 1e-15 * abs(t1)):  # no sliver steps before a kink
            h_step = t1 - t
            last = True
        else:
            h_step = h
        # stages (the valve position at each stage time)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * DP_A21 * k1[i]
        rhs(flags, tmp, _valve_at(v0, v_rate, t + DP_C2 * h_step - t0), q_cmd, p, k2, diag)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * (DP_A31 * k1[i] + DP_A32 * k2[i])
        rhs(flags, tmp, _valve_at(v0, v_rate, t + DP_C3 * h_step - t0), q_cmd, p, k3, diag)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * (DP_A41 * k1[i] + DP_A42 * k2[i] + DP_A43 * k3[i])
        rhs(flags, tmp, _valve_at(v0, v_rate, t + DP_C4 * h_step - t0), q_cmd, p, k4, diag)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * (
                DP_A51 * k1[i] + DP_A52 * k2[i] + DP_A53 * k3[i] + DP_A54 * k4[i]
            )
        rhs(flags, tmp, _valve_at(v0, v_rate, t + DP_C5 * h_step - t0), q_cmd, p, k5, diag)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * (
                DP_A61 * k1[i] + DP_A62 * k2[i] + DP_A63 * k3[i] + DP_A64 * k4[i] + DP_A65 * k5[i]
            )
        v_end = _valve_at(v0, v_rate, t + h_step - t0)
        rhs(flags, tmp, v_end, q_cmd, p, k6, diag)
        for i in range(N_INTEGRATED):
            tmp[i] = y[i] + h_step * (
                DP_B1 * k1[i] + DP_B3 * k3[i] + DP_B4 * k4[i] + DP_B5 * k5[i] + DP_B6 * k6[i]
            )
        rhs(flags, tmp, v_end, q_cmd, p, k7, diag)
        stats[S_RHS] += 6
        for i in range(N_INTEGRATED):
            e[i] = (
                DP_E1 * k1[i]
                + DP_E3 * k3[i]
                + DP_E4 * k4[i]
                + DP_E5 * k5[i]
                + DP_E6 * k6[i]
                + DP_E7 * k7[i]
            )
        err = _err_norm(y, tmp, e, h_step, rtol, atol)
        if not math.isfinite(err):
            err = 1e10
        if err <= 1.0:
            # accepted: dense output for the requested times inside (t, t + h]
            t_new = t1 if last else t + h_step
            while j < n_out and t_out[j] <= t_new:
                s = (t_out[j] - t) / h_step
                s = min(max(s, 0.0), 1.0)
                h00 = (1.0 + 2.0 * s) * (1.0 - s) * (1.0 - s)
                h10 = s * (1.0 - s) * (1.0 - s)
                h01 = s * s * (3.0 - 2.0 * s)
                h11 = s * s * (s - 1.0)
                for i in range(N_INTEGRATED):
                    out[j, i] = (
                        h00 * y[i] + h10 * h_step * k1[i] + h01 * tmp[i] + h11 * h_step * k7[i]
                    )
                out[j, Y_VALVE] = _valve_at(v0, v_rate, t_out[j] - t0)
                j += 1
            for i in range(NY):
                y_old[i] = y[i]
            for i in range(N_INTEGRATED):
                y[i] = tmp[i]
                k1[i] = k7[i]
            y[Y_VALVE] = v_end
            status = _check(y, p)
            if status != OK:
                for i in range(NY):
                    y[i] = y_old[i]
                stats[S_T_DONE] = t
                return status, j, t
            t = t_new
            stats[S_ACCEPTED] += 1
            err = max(err, 1e-10)
            fac = ADAPT_SAFETY * err ** (-0.2 + 0.75 * ADAPT_BETA) * mem[M_ERR] ** ADAPT_BETA
            fac = min(ADAPT_FAC_MAX, max(ADAPT_FAC_MIN, fac))
            mem[M_ERR] = err
            if not last:
                h = h_step * fac
            else:
                # keep the step the controller wants for the next call (clipping at t1 is not a
                # verdict)
                h = max(h, h_step * fac)
        else:
            stats[S_REJECTED] += 1
            fac = max(ADAPT_FAC_MIN, ADAPT_SAFETY * err**-0.2)
            h = h_step * min(fac, 1.0)
        if h < ADAPT_H_MIN and t < t1:
            stats[S_T_DONE] = t
            return ERR_SUBSTEPS, j, t
        steps += 1
        if steps > ADAPT_MAX_STEPS:
            stats[S_T_DONE] = t
            return ERR_SUBSTEPS, j, t
    mem[M_H] = h
    stats[S_T_DONE] = t
    return OK, j, t


@njit(cache=True, nogil=True, fastmath=False)
def _adaptive_advance(flags, y, mem, p, q_cmd, valve_cmd, duration, rtol, atol, t_out, out, stats):
    """
    Advance y (NY components) by `duration` seconds holding the command, adaptively.

    mem (NMEM) carries the controller between calls. Writes the state at each t_out[j] in (0,
    duration] (increasing) to out[j]. Returns (status, outputs written); stats: see S_*. On a fault
    y is the last accepted state and stats[S_T_DONE] its time.
    """
    ks = np.empty((8, NY))
    tmp = np.empty(NY)
    y_old = np.empty(NY)
    diag = np.empty(ND)
    for i in range(NSTATS):
        stats[i] = 0.0
    if q_cmd != mem[M_Q] or valve_cmd != mem[M_VALVE]:
        mem[M_H] = 0.0  # a command change: the inputs jump, restart the controller
        mem[M_Q] = q_cmd
        mem[M_VALVE] = valve_cmd
    n_written = 0
    if not duration > 0.0:
        return OK, n_written
    v0 = y[Y_VALVE]
    t = 0.0
    if v0 <= 0.0 < valve_cmd:
        # a shut valve cracks open to its seat at once, then moves at its stroke rate
        v0 = VALVE_SEAT
        y[Y_VALVE] = v0
    if valve_cmd != v0 and abs(valve_cmd - v0) <= 1e-12 and not (valve_cmd <= 0.0 < v0):
        y[Y_VALVE] = valve_cmd  # a round-off remainder of a ramp: no sliver segment
        v0 = valve_cmd
    if valve_cmd != v0:
        rate = p[P_VALVE_RATE]
        # a valve closing to 0 seals when it reaches its seat (at once from below it: a state set
        # from outside, as the fixed step does after its step)
        ramp_end = valve_cmd if valve_cmd > 0.0 else min(VALVE_SEAT, v0)
        t_ramp = abs(ramp_end - v0) / rate
        if abs(t_ramp - duration) <= 1e-12 * duration:
            t_ramp = duration  # the ramp ends with the call (round-off of the stroke arithmetic)
        v_rate = rate if valve_cmd > v0 else -rate
        t_end = min(t_ramp, duration)
        status, n_written, t = _segment(
            flags,
            y,
            p,
            q_cmd,
            v0,
            v_rate,
            0.0,
            t_end,
            rtol,
            atol,
            mem,
            t_out,
            out,
            n_written,
            stats,
            ks,
            tmp,
            y_old,
            diag,
        )
        if status != OK:
            return status, n_written
        if t_ramp <= duration:
            # the valve reached its command: a kink in the input, restart the controller there
            mem[M_H] = 0.0
            if valve_cmd <= 0.0 < v0:
                _seal(flags, y, p)
            else:
                y[Y_VALVE] = valve_cmd
            status = _check(y, p)
            if status != OK:
                stats[S_T_DONE] = t
                return status, n_written
    if t < duration:
        status, n_written, t = _segment(
            flags,
            y,
            p,
            q_cmd,
            y[Y_VALVE],
            0.0,
            t,
            duration,
            rtol,
            atol,
            mem,
            t_out,
            out,
            n_written,
            stats,
            ks,
            tmp,
            y_old,
            diag,
        )
        if status != OK:
            return status, n_written
    stats[S_T_DONE] = duration
    return OK, n_written


@njit(cache=True, nogil=True, fastmath=False)
def adaptive_advance(flags, y, mem, p, q_cmd, valve_cmd, duration, rtol, atol, t_out, out, stats):
    """Entry point: specialise on the term set (see module docstring)."""
    return _adaptive_advance(
        literally(flags), y, mem, p, q_cmd, valve_cmd, duration, rtol, atol, t_out, out, stats
    )


# numba keys this file's cache on this file alone: drop it when a module compiled in changes
drop_stale_cache(advance, (model_io,))
