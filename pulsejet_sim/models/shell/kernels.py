"""
Numba kernels of the axisymmetric Reissner shell mantle (paper 000).

No ROS, no Python objects.

Discretisation (see shell.py for the full model description)
-------------------------------------------------------------
Nodes i = 0..N carry ``(r_i, z_i, theta_i)``; dof index ``3 i + k`` (k = 0 r, 1 z, 2 theta).
Element e joins nodes e, e+1 and is evaluated at its midpoint (one-point, reduced integration:
no shear locking, and the hoop terms only ever see ``r0`` at element midpoints, which is > 0
even next to the pole -> no polar singularity)::

    r_X = (r_{e+1} - r_e)/ds,  z_X = (z_{e+1} - z_e)/ds,  theta_m = (theta_e + theta_{e+1})/2
    lambda = r_X cos th + z_X sin th,  eta = -r_X sin th + z_X cos th,
    mu = (theta_{e+1}-theta_e)/ds
    tau = r_m / r0_m,  varsigma = sin th / r0_m
    e11 = (lambda^2 + eta^2 - 1)/2        e22 = (tau^2 - tau_d^2)/2      gamma = eta - eta0
    d11 = mu0 lambda0 - mu lambda         d22 = varsigma0 - tau varsigma

``ds`` is the reference chord, ``eta0, lambda0, mu0, varsigma0`` are the *discrete* reference
values, so the sampled reference shape is exactly stress free.  ``tau_d`` is the muscle's
desired hoop stretch (1 when passive).

Stored energy (Kelvin-Voigt elastic part, h the half-thickness, A_e = 2 pi r0_m ds)::

    W_e = A_e [ Psi/2 (e11^2 + 2 nu e11 e22 + e22^2) + Js Psi/2 (d11^2 + 2 nu d11 d22 + d22^2)
                + G_s/2 gamma^2 ]
    Psi = 2 E h/(1-nu^2),  Js = h^2/3,  G_s = 2 h G,  G = E/(2(1+nu))

With ``material.law: neo_hookean`` (flag F_NEO_HOOKEAN) the membrane term ``Psi/2 (..e..)`` is
replaced by an incompressible neo-Hookean sheet's energy (``neo_hookean_membrane``;
docs/theory/shell_rubber.md).

Internal forces are exactly ``-dW/dq = -B^T sigma`` (B = d strain / dq), so without viscosity
and fluid loads the semi-discrete system is Hamiltonian.  The Kelvin-Voigt viscous forces come
from the dissipation function ``D = A_e [Psi2/2 (.. rates ..) + Js Psi2/2 (..) + G_v/2
gamma_dot^2]`` (``Psi2 = 6 eta_v h/(1-nu^2)``, ``G_v = 2 h eta_v``): ``f_v = -B^T D_v B q_dot``,
power ``2D >= 0``.

Velocities: radial and angular velocities are relative to the body (= absolute for r), the axial
velocity of each node is stored **absolute** (``w = z_dot + U``, U the vehicle speed), which
makes the mass matrix block diagonal: shell nodes and vehicle only interact through the forces
at the clamped ring, the cavity pressure and the jet.
"""

from __future__ import annotations

from collections import namedtuple
import math

from numba import literally, njit
import numpy as np
from pulsejet_sim.core.kernel_cache import drop_stale_cache
from pulsejet_sim.models import cable_pulse, starting_jet as sj
from pulsejet_sim.models.cable_pulse import activation as pulse_activation

# ---- flags (bitmask; compiled out only by advance_specialised via numba.literally) -----------
F_VISC = 1
F_DRAG = 2
F_JET = 4
F_BODY = 8
F_CABLE = 16
F_MUSCLE = 32
F_ROUTINE = 64
# paper 000's coupling (Fig. 5 and the paragraph before its state-space form): the shell is solved
# in the body frame with only drag and added mass from the water (no cavity pressure on the wall),
# and the vehicle is driven by the jet thrust alone; the vehicle velocity enters only the
# kinematics (the position update)
F_PAPER = 128
# the outlet is the mantle's own free edge: A_out(t) = pi r_edge(t)^2 (paper 000 section 5)
F_EDGE = 256
# the authors' code as written (coupling paper_code, for auditing it; docs/validation/papers.md):
# pole clamped to the body, edge free, fixed nozzle, no cavity pressure and no
# tangential drag on the wall; thrust, refilling force and body drag loaded on the wall as a
# uniform axial load per reference area; the vehicle (consistent frame, monolithic) feels them
# through the clamped pole's axial reaction
F_CODE = 512
# material.law neo_hookean: the membrane part of the element energy is an incompressible
# neo-Hookean sheet's (element_force; docs/theory/shell_rubber.md), bending and transverse shear
# keep the linear terms with nu = 1/2 (P_NU), so mu h = Psi/8 (Psi = 2 E h/(1 - nu^2), E = 3 mu)
F_NEO_HOOKEAN = 1024

# ---- parameter vector P ---------------------------------------------------------------------
P_PSI, P_PSI2, P_JS, P_GS, P_GV, P_NU = 0, 1, 2, 3, 4, 5
P_RHO, P_AOUT, P_AIN, P_CF, P_CT, P_CD = 6, 7, 8, 9, 10, 11
P_MBODY, P_AMP, P_FREQ, P_TC, P_TR = 12, 13, 14, 15, 16
P_DT, P_ALPHA, P_TOL, P_RLIM, P_QLIM, P_MAXIT, P_DELAY, P_V0, P_VLIM = (
    17,
    18,
    19,
    20,
    21,
    22,
    23,
    24,
    25,
)
P_PSTAT = 26  # static gauge pressure load on the inner surface (test/load scenes), Pa
P_HC, P_KC = 27, 28  # axis contact: radius where the inner faces meet, penalty stiffness per area
P_VSCALE = 29  # Newton velocity scale: shortest element / dt (converged when a step moves a
# node by less than newton_tolerance times the shortest element)
P_MSHELL = 30  # mass of the moving shell, kg (carried by the vehicle in the paper coupling)
P_PULSE = 31  # the routine's pulse: PULSE_HALF_COSINE or PULSE_TRIANGLE
# inertance of the water inside the cavity, 1/m (fluid.internal_inertia: one_dimensional): its
# kinetic energy is 1/2 rho Lambda V'^2 (0: the water inside carries no inertia of its own)
P_LAMBDA = 32
# 1: Lambda follows the current shape (fluid.internal_inertia: one_dimensional_deforming)
P_LAMBDA_DEFORMING = 33
# length S, m, of that flow's momentum relative to the body, rho S V' along +z
# (fluid.internal_flow_momentum: true; 0: left out)
P_SMOM = 34
# the starting jet's formation number F (jet.starting_jet, models/starting_jet.py); 0: term off
P_FORMATION_NUMBER = 35
N_PARAMS = 36
PULSE_HALF_COSINE, PULSE_TRIANGLE = 0.0, 1.0

# ---- element table E[e, :] -------------------------------------------------------------------
E_DS, E_R0M, E_LAM0, E_ETA0, E_K0, E_VS0, E_SMUS, E_AREA = 0, 1, 2, 3, 4, 5, 6, 7
N_ECOLS = 8

# ---- node table Nd[i, :] --------------------------------------------------------------------
N_MRR, N_MRZ, N_MZZ, N_MTT, N_FIXR, N_FIXZ, N_FIXT, N_WC, N_DAREA, N_HC = (
    0,
    1,
    2,
    3,
    4,
    5,
    6,
    7,
    8,
    9,
)
# paper_code: the node's work-equivalent share of the wall-borne axial load (uniform per reference
# area over the deformable wall, shares summing to 1; shell.consistent_area_shares)
N_WWALL = 10
N_NCOLS = 11

# ---- state tail (after q[3 n1] and v[3 n1]) ------------------------------------------------
S_X, S_U, S_A, S_IN, S_JET, S_DRAG, S_VISC, S_OTHER = 0, 1, 2, 3, 4, 5, 6, 7
S_THR, S_BDRAG, S_UJ, S_P, S_VOL, S_VDOT, S_TIME = 8, 9, 10, 11, 12, 13, 14
S_NIT, S_NJAC = 15, 16  # cumulative Newton iterations and Jacobian factorisations (diagnostics)
S_CREATED = 17  # paper coupling: the jet's kinetic energy that no wall force pays for, J
S_CREATED_WALL = (
    18  # paper_code: work of the wall-borne thrust, refill force and drag beyond the books, J
)
# paper coupling, the water's momentum: work of the unreacted -rho S V'' on the body, J
S_CREATED_MOM = 19
# jet.starting_jet (models/starting_jet.py): the current pulse's formation time int u_j/D dt, and
# the exit over-pressure's work that left with the jet (part of S_JET), J
S_FORMATION_TIME, S_OVERPRESSURE_WORK = 20, 21
# jet.starting_jet: the current pulse's running peak outflow (the most negative end-of-step volume
# rate, m^3/s, <= 0), reset with the formation time: only an outflow beyond it books over-pressure
S_PEAK_OUTFLOW = 22
# jet.starting_jet: the previous step's booked outflow rise (m^3/s, <= 0), the rate before
# pinch-off that the step crossing T* = F books its share at
S_LAST_RISE = 23
N_TAIL = 24

# ---- stats returned by the force evaluation -------------------------------------------------
T_EEL, T_PVISC, T_PDRAG, T_VOL, T_VDOT, T_P, T_PACT, T_FRING, T_RMAX, T_PCONT = (
    0,
    1,
    2,
    3,
    4,
    5,
    6,
    7,
    8,
    9,
)
T_AOUT = 10  # outlet area, m^2
T_WREL = 11  # paper_code: area-weighted mean axial wall velocity relative to the body, m/s
T_FREF = 12  # paper_code: the refilling force (<= 0), N
N_STATS = 13

# blow-up codes
OK, ERR_NONFINITE, ERR_AXIS, ERR_BOUNDS, ERR_NEWTON, ERR_FOLD = 0, 1, 2, 3, 4, 5
BW = 5  # half bandwidth of the dof ordering
# the Newton workspace's flags (advance_kept): a reusable factorisation, a predictor history
WS_HAVE_LU, WS_HAVE_PREV = 0, 1
WS_LEN = 2


@njit(cache=True, nogil=True)
def routine(t, P):
    """
    Return the activation a(t) in [0, 1] and da/dt of the periodic routine.

    models/cable_pulse.py's pull (the controller's CableRoutine evaluates the same function), with
    the timing packed in P: P_DELAY, P_FREQ, P_TC, P_TR and P_PULSE = PULSE_TRIANGLE for lines.
    """
    triangle = P[P_PULSE] == PULSE_TRIANGLE
    return pulse_activation(t, P[P_DELAY], P[P_FREQ], P[P_TC], P[P_TR], triangle)


@njit(cache=True, nogil=True)
def contact(r, hc, k):
    """
    Axis contact barrier for r < hc.

    Force f = k hc (hc/r - 1) (outward), energy k hc (hc ln(hc/r) - (hc - r)), stiffness
    df/dr = -k hc^2/r^2; below r = hc/10 it continues linearly (C1) so that a Newton iterate on the
    wrong side of the axis stays finite. Returns (force, energy, -df/dr).
    """
    r1 = 0.1 * hc
    if r >= r1:
        return (
            k * hc * (hc / r - 1.0),
            k * hc * (hc * math.log(hc / r) - (hc - r)),
            k * hc * hc / (r * r),
        )
    f1 = k * hc * (hc / r1 - 1.0)
    e1 = k * hc * (hc * math.log(hc / r1) - (hc - r1))
    s1 = k * hc * hc / (r1 * r1)
    d = r1 - r
    return f1 + s1 * d, e1 + f1 * d + 0.5 * s1 * d * d, s1


@njit(cache=True, nogil=True)
def element_strain(q6, ds, r0m, lam0, eta0, k0, vs0, taud, B):
    """Strains (e11, e22, gamma, d11, d22) of one element and their gradient B (5 x 6)."""
    r1, z1, t1, r2, z2, t2 = q6[0], q6[1], q6[2], q6[3], q6[4], q6[5]
    rX = (r2 - r1) / ds
    zX = (z2 - z1) / ds
    th = 0.5 * (t1 + t2)
    c = math.cos(th)
    s = math.sin(th)
    lam = rX * c + zX * s
    eta = -rX * s + zX * c
    mu = (t2 - t1) / ds
    tau = 0.5 * (r1 + r2) / r0m
    vs = s / r0m
    e11 = 0.5 * (rX * rX + zX * zX - 1.0)
    e22 = 0.5 * (tau * tau - taud * taud)
    gam = eta - eta0
    d11 = k0 - mu * lam
    d22 = vs0 - tau * vs
    ids = 1.0 / ds
    # e11
    B[0, 0] = -rX * ids
    B[0, 1] = -zX * ids
    B[0, 2] = 0.0
    B[0, 3] = rX * ids
    B[0, 4] = zX * ids
    B[0, 5] = 0.0
    # e22
    g = 0.5 * tau / r0m
    B[1, 0] = g
    B[1, 1] = 0.0
    B[1, 2] = 0.0
    B[1, 3] = g
    B[1, 4] = 0.0
    B[1, 5] = 0.0
    # gamma = eta - eta0
    B[2, 0] = s * ids
    B[2, 1] = -c * ids
    B[2, 2] = -0.5 * lam
    B[2, 3] = -s * ids
    B[2, 4] = c * ids
    B[2, 5] = -0.5 * lam
    # d11 = k0 - mu lam ; dlam = (-c/ds, -s/ds, eta/2, c/ds, s/ds, eta/2) ;
    # dmu = (0,0,-1/ds,0,0,1/ds)
    B[3, 0] = mu * c * ids
    B[3, 1] = mu * s * ids
    B[3, 2] = lam * ids - 0.5 * mu * eta
    B[3, 3] = -mu * c * ids
    B[3, 4] = -mu * s * ids
    B[3, 5] = -lam * ids - 0.5 * mu * eta
    # d22 = vs0 - tau vs
    g2 = -0.5 * vs / r0m
    g3 = -0.5 * tau * c / r0m
    B[4, 0] = g2
    B[4, 1] = 0.0
    B[4, 2] = g3
    B[4, 3] = g2
    B[4, 4] = 0.0
    B[4, 5] = g3
    return e11, e22, gam, d11, d22


@njit(cache=True, nogil=True)
def element_force(flags, q6, v6, Erow, taud, P, B, f6, out):
    """
    Elastic + viscous generalised force on the 6 element dofs (into f6, overwritten).

    out[0] = elastic energy, out[1] = viscous power (>= 0), out[2] = -dW/dtau_d at fixed q, the
    muscle's active force (for its power; linear law: the hoop resultant times area times tau_d).
    The membrane part is the linear law's, or with F_NEO_HOOKEAN `neo_hookean_membrane`.
    """
    ds = Erow[E_DS]
    A = Erow[E_AREA]
    e11, e22, gam, d11, d22 = element_strain(
        q6, ds, Erow[E_R0M], Erow[E_LAM0], Erow[E_ETA0], Erow[E_K0], Erow[E_VS0], taud, B
    )
    psi = P[P_PSI]
    nu = P[P_NU]
    pj = psi * P[P_JS]
    if flags & F_NEO_HOOKEAN:
        s0, s1, membrane, active = neo_hookean_membrane(e11, e22, taud, 0.125 * psi)
        s0 *= A
        s1 *= A
        s2 = A * P[P_GS] * gam
        s3 = A * pj * (d11 + nu * d22)
        s4 = A * pj * (d22 + nu * d11)
        energy = A * membrane + 0.5 * A * (
            pj * (d11 * d11 + 2 * nu * d11 * d22 + d22 * d22) + P[P_GS] * gam * gam
        )
        active *= A
    else:
        s0 = A * psi * (e11 + nu * e22)
        s1 = A * psi * (e22 + nu * e11)
        s2 = A * P[P_GS] * gam
        s3 = A * pj * (d11 + nu * d22)
        s4 = A * pj * (d22 + nu * d11)
        energy = (
            0.5
            * A
            * (
                psi * (e11 * e11 + 2 * nu * e11 * e22 + e22 * e22)
                + pj * (d11 * d11 + 2 * nu * d11 * d22 + d22 * d22)
                + P[P_GS] * gam * gam
            )
        )
        active = s1 * taud
    pvisc = 0.0
    if flags & F_VISC:
        r0 = 0.0
        r1 = 0.0
        r2 = 0.0
        r3 = 0.0
        r4 = 0.0
        for j in range(6):
            vj = v6[j]
            r0 += B[0, j] * vj
            r1 += B[1, j] * vj
            r2 += B[2, j] * vj
            r3 += B[3, j] * vj
            r4 += B[4, j] * vj
        psi2 = P[P_PSI2]
        pj2 = psi2 * P[P_JS]
        v0 = A * psi2 * (r0 + nu * r1)
        v1 = A * psi2 * (r1 + nu * r0)
        v2 = A * P[P_GV] * r2
        v3 = A * pj2 * (r3 + nu * r4)
        v4 = A * pj2 * (r4 + nu * r3)
        pvisc = v0 * r0 + v1 * r1 + v2 * r2 + v3 * r3 + v4 * r4
        s0 += v0
        s1v = s1 + v1
        s2 += v2
        s3 += v3
        s4 += v4
    else:
        s1v = s1
    for j in range(6):
        f6[j] = -(B[0, j] * s0 + B[1, j] * s1v + B[2, j] * s2 + B[3, j] * s3 + B[4, j] * s4)
    out[0] = energy
    out[1] = pvisc
    out[2] = active
    return energy


@njit(cache=True, nogil=True)
def neo_hookean_membrane(e11, e22, taud, mu_h):
    """
    Incompressible neo-Hookean membrane: resultants, energy and active force per reference area.

    W = mu h (l1^2 + l2^2 + 1/(l1^2 l2^2) - 3), h the half-thickness (2h thick), with
    l1^2 = 1 + 2 e11 (meridian) and the elastic hoop stretch l2 = tau/tau_d (active strain:
    the muscle's desired stretch tau_d is a volume-preserving active deformation, Ambrosi &
    Pezzuto 2012), e22 = (tau^2 - tau_d^2)/2.  With x = l1^2 - 1 and y = l2^2 - 1,
    W = mu h (x^2 + x y + y^2 + x y (x + y)) / ((1 + x)(1 + y)), exact and free of the
    cancellation of the first form at small strain.  Returns (N11 = dW/de11, N22 = dW/de22,
    W, -dW/dtau_d at fixed q); every stretch product l1^2 l2^2 > 0, else the resultants are
    NaN (the step then fails and says so: docs/theory/shell_rubber.md).
    """
    x = 2.0 * e11
    ti = 1.0 / (taud * taud)
    y = 2.0 * e22 * ti
    a = 1.0 + x
    b = 1.0 + y
    ab = a * b
    if not ab > 0.0:
        return math.nan, math.nan, math.inf, math.nan
    w = mu_h * (x * x + x * y + y * y + x * y * (x + y)) / ab
    # dW/dx = mu h (1 - 1/(a^2 b)) = mu h (x (2 + x) + a^2 y)/(a^2 b), and alike in y
    dwdx = mu_h * (x * (2.0 + x) + a * a * y) / (a * ab)
    dwdy = mu_h * (y * (2.0 + y) + b * b * x) / (ab * b)
    # dy/de22 = 2/tau_d^2; dy/dtau_d = -2 (1 + y)/tau_d at fixed tau
    return 2.0 * dwdx, 2.0 * ti * dwdy, w, 2.0 * dwdy * b / taud


@njit(cache=True, nogil=True)
def volume_grad(q, n1, g):
    """
    Cavity volume between the shell and the ring plane, and its gradient.

    V = sum of frusta pi/3 (r_i^2 + r_i r_j + r_j^2)(z_i - z_j), and its gradient g (dofs 3i,
    3i+1).
    """
    for k in range(3 * n1):
        g[k] = 0.0
    V = 0.0
    for e in range(n1 - 1):
        ra = q[3 * e]
        za = q[3 * e + 1]
        rb = q[3 * e + 3]
        zb = q[3 * e + 4]
        S = ra * ra + ra * rb + rb * rb
        dz = za - zb
        V += math.pi / 3.0 * S * dz
        g[3 * e] += math.pi / 3.0 * (2 * ra + rb) * dz
        g[3 * e + 3] += math.pi / 3.0 * (ra + 2 * rb) * dz
        g[3 * e + 1] += math.pi / 3.0 * S
        g[3 * e + 4] -= math.pi / 3.0 * S
    return V


@njit(cache=True, nogil=True)
def outlet_area(flags, q, n1, P):
    """Outlet area, m^2: the fixed ``A_out``, or pi r_edge^2 when the free edge is the nozzle."""
    if flags & F_EDGE:
        r = q[3 * (n1 - 1)]
        return math.pi * r * r
    return P[P_AOUT]


@njit(cache=True, nogil=True)
def jet_terms(Vdot, U, P, A_out):
    """
    Jet model: returns (p, u_j, thrust, ram, P_jet_out, P_other).

    Outflow (V' < 0): u_j = -V'/A_out, p = rho u_j^2 / 2 on the inner surface (the shell pays the
    jet's kinetic energy flux), thrust C_f rho A_out u_j^2; earth-frame jet energy flux
    rho A u_j (u_j - U)^2 / 2; a C_f != 1 mismatch (1 - C_f) rho A u_j^2 U is booked as 'other'.
    Inflow (V' > 0) through A_in: suction p = -rho u_in^2 / 2, the inflow kinetic energy and the
    ram loss of bringing the ingested water to the vehicle speed (ram force rho V' U) mix away.
    """
    rho = P[P_RHO]
    if Vdot < 0.0:
        A = A_out
        u = -Vdot / A
        p = 0.5 * rho * u * u
        thr = P[P_CF] * rho * A * u * u
        du = u - U
        return p, u, thr, 0.0, 0.5 * rho * A * u * du * du, (1.0 - P[P_CF]) * rho * A * u * u * U
    A = P[P_AIN]
    u = Vdot / A
    p = -0.5 * rho * u * u
    ram = rho * Vdot * U
    return p, -u, 0.0, ram, 0.0, 0.5 * rho * A * u * u * u + 0.5 * rho * Vdot * U * U


@njit(cache=True, nogil=True)
def code_rim(Nd):
    """paper_code: the node of the clamped rim (the last node held axially by the body)."""
    kc = 0
    for i in range(Nd.shape[0]):
        if Nd[i, N_FIXZ] > 0.5:
            kc = i
    return kc


@njit(cache=True, nogil=True, inline='always')
def chord(q, e):
    """Element e's current chord: its direction (cos, sin) from node e to e + 1 and length."""
    dr = q[3 * e + 3] - q[3 * e]
    dz = q[3 * e + 4] - q[3 * e + 1]
    ln = math.sqrt(dr * dr + dz * dz)
    if not ln > 0.0:
        return 1.0, 0.0, 0.0
    return dr / ln, dz / ln, ln


@njit(cache=True, nogil=True)
def forces(flags, q, v, U, t, amp_cmd, E, Nd, P, F, gV, vrel, st):
    """
    Compute all generalised forces on the shell dofs at (q, v, U, t), into F.

    F includes the reactions on constrained dofs. Fills st (stats), gV (volume gradient), vrel
    (velocities rel. body).
    """
    n1 = Nd.shape[0]
    n = 3 * n1
    ne = n1 - 1
    for k in range(n):
        F[k] = 0.0
    for i in range(n1):
        vrel[3 * i] = v[3 * i] * (1.0 - Nd[i, N_FIXR])
        vrel[3 * i + 1] = (v[3 * i + 1] - U) * (1.0 - Nd[i, N_FIXZ])
        vrel[3 * i + 2] = v[3 * i + 2] * (1.0 - Nd[i, N_FIXT])
    # activation
    a = 1.0
    adot = 0.0
    if flags & F_ROUTINE:
        a, adot = routine(t, P)
    B = np.empty((5, 6))
    f6 = np.empty(6)
    q6 = np.empty(6)
    v6 = np.empty(6)
    out = np.empty(3)
    eel = 0.0
    pvisc = 0.0
    pact = 0.0
    for e in range(ne):
        for j in range(6):
            q6[j] = q[3 * e + j]
            v6[j] = vrel[3 * e + j]
        taud = 1.0
        if flags & F_MUSCLE:
            taud = 1.0 - P[P_AMP] * a * E[e, E_SMUS]
        element_force(flags, q6, v6, E[e], taud, P, B, f6, out)
        eel += out[0]
        pvisc += out[1]
        if flags & F_MUSCLE:
            # dW/dt at fixed q: dW/dtau_d * dtau_d/dt = (-out[2]) * (-amp adot s), out[2] being
            # -dW/dtau_d (linear law: s22 tau_d)
            pact += out[2] * P[P_AMP] * adot * E[e, E_SMUS]
        for j in range(6):
            F[3 * e + j] += f6[j]
    # contact at the axis: when the wall's midsurface comes closer to the axis than the contact
    # radius h_c (its inner face meets the opposite wall), a conservative barrier pushes it back
    # The impact is made inelastic by a critically damped dashpot on the radial velocity while in
    # contact (wet soft walls do not bounce); its dissipation is booked under out_other.
    pcont = 0.0
    for i in range(n1):
        if Nd[i, N_FIXR] > 0.5:
            continue
        hc = Nd[i, N_HC]
        if q[3 * i] < hc:
            f, en, kk = contact(q[3 * i], hc, P[P_KC] * Nd[i, N_DAREA])
            cd = 2.0 * math.sqrt(kk * Nd[i, N_MRR])
            fd = -cd * vrel[3 * i]
            F[3 * i] += f + fd
            eel += en
            pcont -= fd * vrel[3 * i]
    # cable: radial inward force with the work-equivalent shares wc of its line load (the held
    # ends' shares are the supports', so the free ones sum to less than 1)
    if flags & F_CABLE:
        fc = amp_cmd
        if flags & F_ROUTINE:
            fc = P[P_AMP] * a
        for i in range(n1):
            f = -fc * Nd[i, N_WC]
            F[3 * i] += f
            pact += f * vrel[3 * i]
    # tangential quadratic drag relative to the water (absolute velocity), element by element:
    # each element half (node i's) takes -1/2 rho C_t (A_e/2) |v_t| v_t along the element's
    # current chord, v_t node i's velocity along that chord. The pole's radial share goes to the
    # axis; the clamped ring (or free edge) moves axially with the vehicle, and its half's axial
    # share goes into the ring's reaction, the vehicle's (docs/theory/shell.md, wall loads)
    pdrag = 0.0
    if (flags & F_DRAG) and not (flags & F_CODE):
        cdr = 0.5 * P[P_RHO] * P[P_CT]
        for e in range(ne):
            c, s, ln = chord(q, e)
            if not ln > 0.0:
                continue
            ch = cdr * 0.5 * E[e, E_AREA]
            for k in range(2):
                i = e + k
                vt = vrel[3 * i] * c + (vrel[3 * i + 1] + U) * s
                f = -ch * abs(vt) * vt
                F[3 * i] += f * c * (1.0 - Nd[i, N_FIXR])
                F[3 * i + 1] += f * s
                pdrag -= f * vt
    # cavity volume and pressure
    V = volume_grad(q, n1, gV)
    Vdot = 0.0
    for k in range(n):
        Vdot += gV[k] * vrel[k]
    p = 0.0
    aout = outlet_area(flags, q, n1, P)
    if (flags & F_JET) and not (flags & F_PAPER) and not (flags & F_CODE):
        p, uj, thr, ram, pj, po = jet_terms(Vdot, U, P, aout)
    wrel = 0.0
    fref = 0.0
    if flags & F_CODE:
        # the authors' code: (thrust + refill force + body drag) per unit reference area, axial, on
        # every node (octopus_derivatives.m: fluid = mod_fluid*[senth;costh;0],
        # zetas_e = [0;0;0;fluid])
        kc = code_rim(Nd)
        rmx = 0.0
        for i in range(n1):
            if q[3 * i] > rmx:
                rmx = q[3 * i]
        load = 0.0
        if flags & F_JET:
            p_, uj_, thr_, ram_, pj_, po_ = jet_terms(Vdot, U, P, aout)
            if Vdot > 0.0:
                fref = -P[P_CF] * P[P_RHO] * Vdot * Vdot / P[P_AIN]
            load = thr_ + fref
        if flags & F_DRAG:
            load -= 0.5 * P[P_CD] * P[P_RHO] * math.pi * rmx * rmx * abs(U) * U
        for i in range(kc, n1):
            wi = Nd[i, N_WWALL]
            F[3 * i + 1] += wi * load
            wrel += wi * vrel[3 * i + 1]
    pst = P[P_PSTAT]
    if pst != 0.0:
        # static load: potential -p_s V, its work p_s V' is booked as input
        pact += pst * Vdot
    if p + pst != 0.0:
        for k in range(n):
            F[k] += (p + pst) * gV[k]
    rmax = 0.0
    for i in range(n1):
        if q[3 * i] > rmax:
            rmax = q[3 * i]
    st[T_EEL] = eel
    st[T_PVISC] = pvisc
    st[T_PDRAG] = pdrag
    st[T_VOL] = V
    st[T_VDOT] = Vdot
    st[T_P] = p
    st[T_PACT] = pact
    st[T_FRING] = F[3 * (n1 - 1) + 1]
    if flags & F_CODE:
        st[T_FRING] = F[3 * code_rim(Nd) + 1]  # the body holds the rim around the pole
    st[T_RMAX] = rmax
    st[T_PCONT] = pcont
    st[T_AOUT] = aout
    st[T_WREL] = wrel
    st[T_FREF] = fref


@njit(cache=True, nogil=True)
def body_terms(flags, st, U, P):
    """
    Vehicle: returns (accel, thrust, body drag (signed, opposes U), ram, P_jet_out, P_other, m).

    In the paper coupling the vehicle carries the shell's mass too (the shell is solved in the body
    frame) and feels no force from the clamped ring: only thrust, drag and the ram of the inflow.
    """
    rho = P[P_RHO]
    thr = 0.0
    ram = 0.0
    pj = 0.0
    po = 0.0
    m = P[P_MBODY]
    if flags & F_PAPER:
        m += P[P_MSHELL]
    if flags & F_JET:
        p, uj, thr, ram, pj, po = jet_terms(st[T_VDOT], U, P, st[T_AOUT])
        m += rho * st[T_VOL]
    else:
        m += rho * P[P_V0]
    drag = 0.0
    if flags & F_DRAG:
        drag = -0.5 * P[P_CD] * rho * math.pi * st[T_RMAX] * st[T_RMAX] * abs(U) * U
    acc = 0.0
    if flags & F_PAPER:
        acc = (thr + drag - ram) / m
    elif flags & F_CODE:
        if flags & F_BODY:
            acc = (
                -ram + st[T_FRING]
            ) / m  # thrust and drag reach the body through the clamped pole
    elif flags & F_BODY:
        acc = (thr + drag - ram + st[T_FRING]) / m
    return acc, thr, drag, ram, pj, po, m


@njit(cache=True, nogil=True)
def apply_minv(Nd, F, out):
    """
    Compute out = M^-1 F on free dofs, 0 on fixed.

    M^-1 F on free dofs: 2x2 node blocks for (r, w), scalar for theta.
    """
    n1 = Nd.shape[0]
    for i in range(n1):
        fr = F[3 * i] * (1.0 - Nd[i, N_FIXR])
        fz = F[3 * i + 1] * (1.0 - Nd[i, N_FIXZ])
        a = Nd[i, N_MRR]
        b = Nd[i, N_MRZ]
        d = Nd[i, N_MZZ]
        if Nd[i, N_FIXR] > 0.5 and Nd[i, N_FIXZ] > 0.5:
            out[3 * i] = 0.0
            out[3 * i + 1] = 0.0
        elif Nd[i, N_FIXR] > 0.5:
            out[3 * i] = 0.0
            out[3 * i + 1] = fz / d
        elif Nd[i, N_FIXZ] > 0.5:
            out[3 * i] = fr / a
            out[3 * i + 1] = 0.0
        else:
            det = a * d - b * b
            out[3 * i] = (d * fr - b * fz) / det
            out[3 * i + 1] = (a * fz - b * fr) / det
        out[3 * i + 2] = 0.0 if Nd[i, N_FIXT] > 0.5 else F[3 * i + 2] / Nd[i, N_MTT]


@njit(cache=True, nogil=True)
def kinetic(Nd, v, U, P, V, flags):
    """
    Return the kinetic energies.

    (shell kinetic incl. rotation, normal added-mass kinetic [included in the node mass blocks],
    vehicle 1/2 M U^2, internal fluid 1/2 rho V U^2).  The node blocks are
    M = m I + B (B the element halves' added mass, sum of m_a,e/2 n_e n_e^T), so the added-mass
    part is split off with the shell's own mass m.
    """
    n1 = Nd.shape[0]
    ksh = 0.0
    for i in range(n1):
        vr = v[3 * i] * (1.0 - Nd[i, N_FIXR])
        vz = v[3 * i + 1] * (1.0 - Nd[i, N_FIXZ])
        vt = v[3 * i + 2] * (1.0 - Nd[i, N_FIXT])
        ksh += 0.5 * (
            Nd[i, N_MRR] * vr * vr
            + 2 * Nd[i, N_MRZ] * vr * vz
            + Nd[i, N_MZZ] * vz * vz
            + Nd[i, N_MTT] * vt * vt
        )
    kveh = 0.5 * P[P_MBODY] * U * U
    if flags & F_PAPER:
        kveh += 0.5 * P[P_MSHELL] * U * U  # node velocities are relative to the body here
    if flags & F_JET:
        kint = 0.5 * P[P_RHO] * V * U * U
    else:
        kint = 0.5 * P[P_RHO] * P[P_V0] * U * U
    return ksh, kveh, kint


# ---------------------------------------------------------------------------------------------
# banded linear algebra (no pivoting: the Newton matrix M/alpha - dt(alpha dt K + C) is
# dominated by its positive mass and stiffness diagonal)
@njit(cache=True, nogil=True)
def band_lu(A, n, bw):
    for k in range(n):
        piv = A[k, bw]
        if piv == 0.0 or not math.isfinite(piv):
            return False
        for i in range(k + 1, min(n, k + bw + 1)):
            l = A[i, k - i + bw] / piv  # noqa: E741
            if l == 0.0:
                continue
            A[i, k - i + bw] = l
            for j in range(k + 1, min(n, k + bw + 1)):
                A[i, j - i + bw] -= l * A[k, j - k + bw]
    return True


@njit(cache=True, nogil=True)
def band_solve(A, n, bw, b, x):
    for i in range(n):
        s = b[i]
        for k in range(max(0, i - bw), i):
            s -= A[i, k - i + bw] * x[k]
        x[i] = s
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(i + 1, min(n, i + bw + 1)):
            s -= A[i, j - i + bw] * x[j]
        x[i] = s / A[i, bw]


@njit(cache=True, nogil=True)
def fixed_dof(Nd, k):
    i = k // 3
    c = k - 3 * i
    if c == 0:
        return Nd[i, N_FIXR] > 0.5
    if c == 1:
        return Nd[i, N_FIXZ] > 0.5
    return Nd[i, N_FIXT] > 0.5


@njit(cache=True, nogil=True)
def assemble_KC(flags, q, vrel, U, t, E, Nd, P, K, C):
    """
    Assemble the banded stiffness K = dF/dq and damping C = dF/dv.

    K: forward differences of the element forces, incl. the geometric part; C: exact viscous
    -B^T D_v B, drag 2x2 blocks. The rank-one pressure term is handled separately
    (Sherman-Morrison).
    """
    n1 = Nd.shape[0]
    ne = n1 - 1
    K[:, :] = 0.0
    C[:, :] = 0.0
    a = 1.0
    if flags & F_ROUTINE:
        a, adot = routine(t, P)
    B = np.empty((5, 6))
    f0 = np.empty(6)
    f1 = np.empty(6)
    q6 = np.empty(6)
    v6 = np.empty(6)
    out = np.empty(3)
    A = np.zeros((5, 5))
    for e in range(ne):
        for j in range(6):
            q6[j] = q[3 * e + j]
            v6[j] = vrel[3 * e + j]
        taud = 1.0
        if flags & F_MUSCLE:
            taud = 1.0 - P[P_AMP] * a * E[e, E_SMUS]
        element_force(flags, q6, v6, E[e], taud, P, B, f0, out)
        for j in range(6):
            h = 1e-7 * (1.0 + abs(q6[j]))
            qs = q6[j]
            q6[j] = qs + h
            element_force(flags, q6, v6, E[e], taud, P, B, f1, out)
            q6[j] = qs
            for i2 in range(6):
                K[3 * e + i2, 3 * e + j - (3 * e + i2) + BW] += (f1[i2] - f0[i2]) / h
        if flags & F_VISC:
            element_strain(
                q6,
                E[e, E_DS],
                E[e, E_R0M],
                E[e, E_LAM0],
                E[e, E_ETA0],
                E[e, E_K0],
                E[e, E_VS0],
                taud,
                B,
            )
            Ar = E[e, E_AREA]
            psi2 = P[P_PSI2]
            nu = P[P_NU]
            pj2 = psi2 * P[P_JS]
            A[0, 0] = Ar * psi2
            A[0, 1] = Ar * psi2 * nu
            A[1, 0] = A[0, 1]
            A[1, 1] = A[0, 0]
            A[2, 2] = Ar * P[P_GV]
            A[3, 3] = Ar * pj2
            A[3, 4] = Ar * pj2 * nu
            A[4, 3] = A[3, 4]
            A[4, 4] = A[3, 3]
            for i2 in range(6):
                for j in range(6):
                    s = 0.0
                    for k1 in range(5):
                        bk = B[k1, i2]
                        if bk == 0.0:
                            continue
                        for k2 in range(5):
                            s += bk * A[k1, k2] * B[k2, j]
                    C[3 * e + i2, j - i2 + BW] -= s
    for i in range(n1):
        if Nd[i, N_FIXR] < 0.5 and q[3 * i] < Nd[i, N_HC]:
            f, en, kk = contact(q[3 * i], Nd[i, N_HC], P[P_KC] * Nd[i, N_DAREA])
            K[3 * i, BW] -= kk
            C[3 * i, BW] -= 2.0 * math.sqrt(kk * Nd[i, N_MRR])
    if (flags & F_DRAG) and not (flags & F_CODE):
        # the element halves' drag (forces): dF/dv exact, and dF/dq through the chord's
        # direction t = d/|d|, d = x_b - x_a: dF_i/dd = -ch (2 |v_t| t w^T + |v_t| v_t P),
        # P = (I - t t^T)/|d|, w = P v
        cdr = 0.5 * P[P_RHO] * P[P_CT]
        for e in range(ne):
            c, s, ln = chord(q, e)
            if not ln > 0.0:
                continue
            ch = cdr * 0.5 * E[e, E_AREA]
            prr = (1.0 - c * c) / ln
            prz = -c * s / ln
            pzz = (1.0 - s * s) / ln
            for k2 in range(2):
                i = e + k2
                vr = vrel[3 * i]
                vz = vrel[3 * i + 1] + U
                vt = vr * c + vz * s
                k = -2.0 * ch * abs(vt)
                C[3 * i, BW] += k * c * c
                C[3 * i, 1 + BW] += k * c * s
                C[3 * i + 1, -1 + BW] += k * c * s
                C[3 * i + 1, BW] += k * s * s
                wr = prr * vr + prz * vz
                wz = prz * vr + pzz * vz
                g = -ch * abs(vt) * vt
                grr = k * c * wr + g * prr
                grz = k * c * wz + g * prz
                gzr = k * s * wr + g * prz
                gzz = k * s * wz + g * pzz
                # d = x_{e+1} - x_e: +G on node e + 1's (r, z) columns, -G on node e's
                for side in range(2):
                    sg = 1.0 if side == 1 else -1.0
                    col = 3 * (e + side)
                    K[3 * i, col - 3 * i + BW] += sg * grr
                    K[3 * i, col + 1 - 3 * i + BW] += sg * grz
                    K[3 * i + 1, col - 3 * i - 1 + BW] += sg * gzr
                    K[3 * i + 1, col + 1 - 3 * i - 1 + BW] += sg * gzz


@njit(cache=True, nogil=True)
def inertance(q, n1, grad):
    """
    Inertance Lambda of the cavity's current shape, 1/m, and its gradient into ``grad``.

    ``Lambda = int (V_b/V)^2 / (pi r^2) dz`` by the trapezoidal rule on the nodes (V_b the volume
    of the frusta between the pole and the node), as Profile.internal_inertance_per_m does on the
    reference; the gradient by reverse accumulation (dofs 3i: r, 3i+1: z; theta 0).
    """
    ne = n1 - 1
    for k in range(3 * n1):
        grad[k] = 0.0
    behind = np.zeros(n1)
    for e in range(ne):
        ra, za, rb, zb = q[3 * e], q[3 * e + 1], q[3 * e + 3], q[3 * e + 4]
        behind[e + 1] = behind[e] + math.pi / 3.0 * (ra * ra + ra * rb + rb * rb) * (za - zb)
    V = behind[ne]
    f = np.zeros(n1)  # f_0 = 0: nothing flows through the pole
    for i in range(1, n1):
        r = q[3 * i]
        f[i] = (behind[i] / V) ** 2 / (math.pi * r * r)
    lam = 0.0
    w = np.zeros(n1)  # dLambda/df_i
    for e in range(ne):
        dz = q[3 * e + 1] - q[3 * e + 4]
        fm = 0.5 * (f[e] + f[e + 1])
        lam += fm * dz
        w[e] += 0.5 * dz
        w[e + 1] += 0.5 * dz
        grad[3 * e + 1] += fm
        grad[3 * e + 4] -= fm
    adj = np.zeros(n1)  # dLambda/d(behind_i) at fixed V, then V = behind[ne] added
    adj_v = 0.0
    for i in range(1, n1):
        r = q[3 * i]
        adj[i] = w[i] * 2.0 * behind[i] / (V * V * math.pi * r * r)
        adj_v -= w[i] * 2.0 * f[i] / V
        grad[3 * i] -= w[i] * 2.0 * f[i] / r
    adj[ne] += adj_v
    acc = 0.0
    for e in range(ne - 1, -1, -1):
        acc += adj[e + 1]  # behind_i sums the frusta e < i
        ra, za, rb, zb = q[3 * e], q[3 * e + 1], q[3 * e + 3], q[3 * e + 4]
        S = ra * ra + ra * rb + rb * rb
        dz = za - zb
        grad[3 * e] += acc * math.pi / 3.0 * (2 * ra + rb) * dz
        grad[3 * e + 3] += acc * math.pi / 3.0 * (ra + 2 * rb) * dz
        grad[3 * e + 1] += acc * math.pi / 3.0 * S
        grad[3 * e + 4] -= acc * math.pi / 3.0 * S
    return lam


@njit(cache=True, nogil=True)
def folded(q, n1):
    """Return whether the meridian turns back along the axis (an element with z_e <= z_{e+1})."""
    for e in range(n1 - 1):
        if q[3 * e + 1] <= q[3 * e + 4]:
            return True
    return False


@njit(cache=True, nogil=True)
def flow_rate(Nd, g, v, u_frame):
    """Cavity volume rate grad V . v_rel, m^3/s, with axial velocities relative to u_frame."""
    Q = 0.0
    for i in range(Nd.shape[0]):
        Q += g[3 * i] * v[3 * i] * (1.0 - Nd[i, N_FIXR])
        Q += g[3 * i + 1] * (v[3 * i + 1] - u_frame) * (1.0 - Nd[i, N_FIXZ])
    return Q


@njit(cache=True, nogil=True)
def end_of_step_flow(Nd, qn, vn, vs, u_mid, u_end, dt, alpha, q_end, g_end, v1):
    """
    Cavity volume rate at the end of an implicit step, m^3/s, from its end shape and velocities.

    Fills ``q_end`` (shape, axial positions moved relative to the frame speed ``u_mid``),
    ``g_end`` (grad V there) and ``v1`` (end velocities); ``u_end`` is the frame's end speed.
    """
    n1 = Nd.shape[0]
    for i in range(n1):
        q_end[3 * i] = qn[3 * i] + dt * vs[3 * i] * (1.0 - Nd[i, N_FIXR])
        q_end[3 * i + 1] = qn[3 * i + 1] + dt * (vs[3 * i + 1] - u_mid) * (1.0 - Nd[i, N_FIXZ])
    volume_grad(q_end, n1, g_end)
    for k in range(3 * n1):
        v1[k] = vn[k] + (vs[k] - vn[k]) / alpha
    return flow_rate(Nd, g_end, v1, u_end)


@njit(cache=True, nogil=True)
def rank_one_coefficient(flags, st, P, dt, inertia):
    """
    Coefficient c of the Newton matrix's rank-one part c g g^T (g = grad V on the free dofs).

    The jet pressure's d(p)/dV' (consistent coupling) plus the internal water's rho Lambda / alpha.
    """
    c = inertia
    if (flags & F_JET) and not (flags & F_PAPER):
        Aj = st[T_AOUT] if st[T_VDOT] < 0 else P[P_AIN]
        c += dt * P[P_RHO] * abs(st[T_VDOT]) / (Aj * Aj)
    return c


@njit(cache=True, nogil=True)
def starting_jet_impulse(
    Nd, qn, vn, vs, Us, U, body, dt, alpha, q_end, g_end, v1, kappa, q_peak, crossing, share,
    last_rise,
):
    """
    jet.starting_jet: the step's exit over-pressure impulse per area ``j`` (Pa s, <= 0), and more.

    From the pulse's running peak outflow ``q_peak`` and the volume rate at the step's end; the
    step that crosses pinch-off books ``share`` of the previous step's rise ``last_rise``
    (models/starting_jet.py, step_overpressure_impulse).  The residual takes ``j grad V`` on the
    wall and ``A j`` on the vehicle's row (the thrust).  Returns (j, the step's outflow rise
    beyond the peak in m^3/s, Q_end in m^3/s).
    """
    u_end = U + (Us - U) / alpha if body else 0.0
    q1 = end_of_step_flow(Nd, qn, vn, vs, Us, u_end, dt, alpha, q_end, g_end, v1)
    j = sj.step_overpressure_impulse(kappa, q_peak, q1, crossing, share, last_rise)
    return j, sj.overpressure_impulse(1.0, q_peak, q1), q1


@njit(cache=True, nogil=True)
def _check(q, v, n1, P):
    for k in range(6 * n1):
        if not math.isfinite(q[k] if k < 3 * n1 else v[k - 3 * n1]):
            return ERR_NONFINITE
    for i in range(n1):
        if q[3 * i] < -P[P_RLIM]:
            return ERR_AXIS
        if abs(q[3 * i]) > P[P_QLIM] or abs(q[3 * i + 1]) > P[P_QLIM]:
            return ERR_BOUNDS
    for k in range(3 * n1):
        if abs(v[k]) > P[P_VLIM]:
            return ERR_BOUNDS
    return OK


@njit(cache=True, nogil=True)
def _rank_three_correction(dv, gf, zz, ze, rz, c, s, n):
    """
    Turn dv = J^-1 R into (J + c g g^T + s (g e^T + e g^T))^-1 R (Woodbury, 2 x 2).

    ``zz = J^-1 g``, ``ze = J^-1 e`` with ``e`` the vehicle's unit row ``rz``: the inertance's
    rank one ``c`` and the internal momentum's symmetric cross term ``s = rho S / alpha`` between
    the wall and the vehicle.
    """
    a11 = 0.0
    a12 = 0.0
    gy = 0.0
    for k in range(n):
        a11 += gf[k] * zz[k]
        a12 += gf[k] * ze[k]
        gy += gf[k] * dv[k]
    a21 = zz[rz]
    a22 = ze[rz]
    ey = dv[rz]
    m00 = 1.0 + c * a11 + s * a21
    m01 = c * a12 + s * a22
    m10 = s * a11
    m11 = 1.0 + s * a12
    b0 = c * gy + s * ey
    b1 = s * gy
    det = m00 * m11 - m01 * m10
    w0 = (b0 * m11 - m01 * b1) / det
    w1 = (m00 * b1 - m10 * b0) / det
    for k in range(n):
        dv[k] -= w0 * zz[k] + w1 * ze[k]


@njit(cache=True, nogil=True)
def _paper_vehicle_midpoint(flags, st, U, alpha, dt, P, impulse):
    """
    Paper coupling: solve for the vehicle's midpoint speed U*.

    U* of m (U* - U)/alpha = dt (T - D(U*) - ram(U*)) - impulse, with the thrust T of the shell's
    midpoint state (the shell does not feel U); ``impulse`` is the step's change of the water
    inside's momentum relative to the body (0 without it); scalar Newton.
    """
    Us = U
    for _ in range(20):
        a, thr, dr, ram, pj, po, m = body_terms(flags, st, Us, P)
        g = m * (Us - U) / alpha - dt * (thr + dr - ram) + impulse
        dg = m / alpha
        if flags & F_DRAG:
            dg += dt * P[P_CD] * P[P_RHO] * math.pi * st[T_RMAX] * st[T_RMAX] * abs(Us)
        if flags & F_JET:
            dg += dt * P[P_RHO] * max(st[T_VDOT], 0.0)
        step = g / dg
        Us -= step
        if abs(step) <= 1e-14 * (1.0 + abs(Us)):
            break
    return Us


# ---- the time step, in stages -------------------------------------------------------------------
# Each stage below is inlined into ``_advance_impl`` at numba's IR level (inline='always'), so the
# compiled step is the one a single long function gives, bit for bit (docs/dev/architecture.md,
# "Kernels: short stages, one compiled body").

# The step's scratch vectors and matrices, allocated once per call by ``_advance_impl`` and shared
# by the stages: the force evaluation's outputs (F, gV, vrel, st), the Verlet kicks' accelerations
# (acc), the step's end and midpoint (q1, v1, vs), the Newton solve's residual, update, corrections
# and matrices (R, dv, zz, gf, K, C, e_u, wz) and the end-of-step flow's shape (q_end, g_end,
# g_lam).  One argument, not nineteen: Python 3.11+ passes a call of more than 30 arguments as
# *args, which numba's inliner refuses.
StepWork = namedtuple(
    'StepWork',
    (
        'F', 'gV', 'vrel', 'st', 'acc', 'q1', 'v1', 'vs', 'R', 'dv', 'zz', 'gf', 'K', 'C', 'e_u',
        'wz', 'q_end', 'g_end', 'g_lam',
    ),
)


@njit(cache=True, nogil=True, inline='always')
def node_positions(Nd, qn, vs, u_frame, h, q1):
    """
    Fill ``q1`` with the node positions ``h`` seconds on from ``qn`` at the velocities ``vs``.

    The axial velocities are absolute and the shell lives in the body frame, which moves at
    ``u_frame`` (m/s): its axial positions advance by ``vs - u_frame``.  Held dofs stay.
    """
    for i in range(Nd.shape[0]):
        q1[3 * i] = qn[3 * i] + h * vs[3 * i] * (1.0 - Nd[i, N_FIXR])
        q1[3 * i + 1] = qn[3 * i + 1] + h * (vs[3 * i + 1] - u_frame) * (1.0 - Nd[i, N_FIXZ])
        q1[3 * i + 2] = qn[3 * i + 2] + h * vs[3 * i + 2] * (1.0 - Nd[i, N_FIXT])


@njit(cache=True, nogil=True, inline='always')
def verlet_step(flags, state, qn, vn, U, t, amp_cmd, E, Nd, P, w):
    """
    Take one explicit kick-drift-kick (velocity Verlet) step from (qn, vn, U) to (q1, v1).

    Velocity-dependent forces use the velocity available at each kick.  The ledger takes the
    step's powers by the trapezoidal rule once the step passed its checks.  Returns (status, the
    vehicle's end speed and its speed over the drift in m/s, its acceleration in m/s^2, thrust and
    body drag in N, cavity pressure in Pa, volume in m^3, volume rate in m^3/s).
    """
    F, gV, vrel, st, acc, q1, v1, vs = w.F, w.gV, w.vrel, w.st, w.acc, w.q1, w.v1, w.vs
    n1 = Nd.shape[0]
    n = 3 * n1
    tail = 6 * n1
    dt = P[P_DT]
    forces(flags, qn, vn, U, t, amp_cmd, E, Nd, P, F, gV, vrel, st)
    a0, thr0, dr0, ram0, pj0, po0, m0 = body_terms(flags, st, U, P)
    pv0 = st[T_PVISC]
    pd0 = st[T_PDRAG] - dr0 * U
    pa0 = st[T_PACT]
    pc0 = st[T_PCONT]
    apply_minv(Nd, F, acc)
    for k in range(n):
        vs[k] = vn[k] + 0.5 * dt * acc[k]
    Uh = U + 0.5 * dt * a0
    node_positions(Nd, qn, vs, Uh, dt, q1)
    forces(flags, q1, vs, Uh, t + dt, amp_cmd, E, Nd, P, F, gV, vrel, st)
    a1, thr1, dr1, ram1, pj1, po1, m1 = body_terms(flags, st, Uh, P)
    apply_minv(Nd, F, acc)
    for k in range(n):
        v1[k] = vs[k] + 0.5 * dt * acc[k]
    U1 = Uh + 0.5 * dt * a1
    code = _check(q1, v1, n1, P)
    if code != OK:
        return code, U1, Uh, a1, thr1, dr1, 0.0, 0.0, 0.0
    state[tail + S_IN] += 0.5 * dt * (pa0 + st[T_PACT])
    state[tail + S_VISC] += 0.5 * dt * (pv0 + st[T_PVISC])
    state[tail + S_DRAG] += 0.5 * dt * (pd0 + st[T_PDRAG] - dr1 * Uh)
    state[tail + S_JET] += 0.5 * dt * (pj0 + pj1)
    state[tail + S_OTHER] += 0.5 * dt * (po0 + po1 + pc0 + st[T_PCONT])
    return OK, U1, Uh, a1, thr1, dr1, st[T_P], st[T_VOL], st[T_VDOT]


@njit(cache=True, nogil=True, inline='always')
def predict_velocities(vn, vprev, alpha, have_prev, vs):
    """Guess ``vs`` for Newton: extrapolate the previous step's velocity change; keep ``vn``."""
    for k in range(vn.shape[0]):
        vs[k] = vn[k] + alpha * (vn[k] - vprev[k]) if have_prev else vn[k]
        vprev[k] = vn[k]


@njit(cache=True, nogil=True, inline='always')
def water_inside_at_start(Nd, qn, vn, u_frame, rho_lam, deforming, lam_start, g, g_lam):
    """
    Return the water inside's volume rate Q (m^3/s) and inertance (1/m) at the step's start.

    Q = grad V . v_rel (docs/theory/shell.md, the water inside); the inertance is the shape's
    own with ``deforming`` (one_dimensional_deforming), else ``lam_start`` unchanged.
    """
    q_start = 0.0
    if rho_lam > 0.0:
        n1 = Nd.shape[0]
        volume_grad(qn, n1, g)
        q_start = flow_rate(Nd, g, vn, u_frame)
        if deforming:
            lam_start = inertance(qn, n1, g_lam)
    return q_start, lam_start


@njit(cache=True, nogil=True, inline='always')
def ring_at_start(flags, state, Nd, qn, vn, u_frame, P, g):
    """
    jet.starting_jet: the forming ring at the step's start (models/starting_jet.py).

    Returns ``ring`` = (its inertance kappa in kg/m^4, 0 when no ring forms; the outlet area in
    m^2; the formation time T*; the pulse's running peak outflow in m^3/s; whether pinch-off,
    T* = F, is predicted within the step; the previous step's booked outflow rise in m^3/s).
    """
    n1 = Nd.shape[0]
    tail = 6 * n1
    kappa = 0.0
    area = 0.0
    crossing = False
    t0 = state[tail + S_FORMATION_TIME]
    if P[P_FORMATION_NUMBER] > 0.0 and sj.forming(t0, P[P_FORMATION_NUMBER]):
        area = outlet_area(flags, qn, n1, P)
        kappa = sj.ring_inertance(P[P_RHO], area)
        volume_grad(qn, n1, g)
        crossing = sj.crosses_formation_number(
            t0, flow_rate(Nd, g, vn, u_frame), area, P[P_DT], P[P_FORMATION_NUMBER]
        )
    return kappa, area, t0, state[tail + S_PEAK_OUTFLOW], crossing, state[tail + S_LAST_RISE]


@njit(cache=True, nogil=True, inline='always')
def ring_impulse(ring, Nd, P, st, qn, vn, vs, Us, U, body, q_end, g_end, v1):
    """
    jet.starting_jet: the step's exit over-pressure impulse per area (Pa s, <= 0) at ``vs``.

    Pinch-off within the step books its share before T* = F, from the midpoint's volume rate
    (``st``, as the formation time's own update).  Returns (that impulse, the step's outflow
    rise beyond the pulse's peak in m^3/s, the end volume rate in m^3/s).
    """
    kappa, area, t0, peak, crossing, last_rise = ring
    dt = P[P_DT]
    share = sj.pinch_off_share(t0, st[T_VDOT], st[T_AOUT], dt, P[P_FORMATION_NUMBER])
    return starting_jet_impulse(
        Nd, qn, vn, vs, Us, U, body, dt, P[P_ALPHA], q_end, g_end, v1, kappa, peak, crossing,
        share, last_rise,
    )


@njit(cache=True, nogil=True, inline='always')
def shell_residual(Nd, vn, vs, F, P, R):
    """Fill R with the shell's residual M (v* - v_n)/alpha - dt F(q*, v*), N s (every dof)."""
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    for i in range(Nd.shape[0]):
        dr_ = (vs[3 * i] - vn[3 * i]) / alpha
        dz_ = (vs[3 * i + 1] - vn[3 * i + 1]) / alpha
        dt_ = (vs[3 * i + 2] - vn[3 * i + 2]) / alpha
        R[3 * i] = Nd[i, N_MRR] * dr_ + Nd[i, N_MRZ] * dz_ - dt * F[3 * i]
        R[3 * i + 1] = Nd[i, N_MRZ] * dr_ + Nd[i, N_MZZ] * dz_ - dt * F[3 * i + 1]
        R[3 * i + 2] = Nd[i, N_MTT] * dt_ - dt * F[3 * i + 2]


@njit(cache=True, nogil=True, inline='always')
def free_rows(Nd, body, rz, gV, R, gf):
    """
    Zero the held dofs' rows of ``R``; ``gf`` = grad V on the free dofs.

    The vehicle's slot ``rz`` stays free when the vehicle is solved with the shell (``body``).
    """
    for k in range(R.shape[0]):
        if fixed_dof(Nd, k) and not (body and k == rz):
            R[k] = 0.0
            gf[k] = 0.0
        else:
            gf[k] = gV[k]


@njit(cache=True, nogil=True, inline='always')
def vehicle_residual(flags, st, U, Us, P, rz, R):
    """
    Set the vehicle's row R[rz] = m (U* - U)/alpha - dt (its forces); return its mass m, kg.

    In paper_code thrust and drag reach the vehicle through the clamped pole (``st[T_FRING]``).
    """
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    ab_, thr_, dr_b, ram_, pj_, po_, mb = body_terms(flags, st, Us, P)
    if flags & F_CODE:
        R[rz] = mb * (Us - U) / alpha - dt * (-ram_ + st[T_FRING])
    else:
        R[rz] = mb * (Us - U) / alpha - dt * (thr_ + dr_b - ram_ + st[T_FRING])
    return mb


@njit(cache=True, nogil=True, inline='always')
def water_inside_residual(
    Nd, P, qn, vn, vs, U, Us, body, rz, water, rho_lam_now, gf, q_end, g_end, g_lam, v1, R
):
    """
    Add the water inside's impulse to R; return the Newton matrix's rho Lambda, kg/m^4.

    Its kinetic energy 1/2 rho Lambda Q^2 gives, by Lagrange's equation, the impulse
    rho Lambda (Q_end - Q_start) grad V on the wall (and on the vehicle's row: it carries the
    frame); with a deforming inertance Lambda at the step's end and start.  Its momentum
    rho S Q relative to the body adds the cross term rho S U Q: the wall feels the uniform
    pressure -rho S U', the vehicle -rho S Q' (docs/theory/shell.md).
    """
    rho_lam, deforming, rho_s, q_start, lam_start = water
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    u_end = U + (Us - U) / alpha if body else 0.0
    q_flow_end = end_of_step_flow(Nd, qn, vn, vs, Us, u_end, dt, alpha, q_end, g_end, v1)
    if deforming:
        lam_end = inertance(q_end, Nd.shape[0], g_lam)
        imp = P[P_RHO] * (lam_end * q_flow_end - lam_start * q_start)
        rho_lam_now = P[P_RHO] * lam_end
    else:
        imp = rho_lam * (q_flow_end - q_start)
    n = R.shape[0]
    for k in range(n):
        R[k] += imp * gf[k]
    if rho_s > 0.0 and body:
        du_ = (Us - U) / alpha
        for k in range(n):
            R[k] += rho_s * du_ * gf[k]
        R[rz] += rho_s * (q_flow_end - q_start)
    return rho_lam_now


@njit(cache=True, nogil=True, inline='always')
def narrowing_pull(Nd, P, st, q1, body, rz, g_lam, R):
    """
    Add the deforming inertance's pull +1/2 rho Q^2 grad Lambda on the wall to R (as -dt ...).

    The flowing water pulls a narrow section narrower, the -1/2 rho u^2 of Bernoulli
    (docs/validation/papers.md); Q is the midpoint's grad V . v_rel, which forces() left in
    ``st`` at (q*, v*).
    """
    dt = P[P_DT]
    inertance(q1, Nd.shape[0], g_lam)
    q_mid = st[T_VDOT]
    for k in range(R.shape[0]):
        if not fixed_dof(Nd, k) or (body and k == rz):
            R[k] -= dt * 0.5 * P[P_RHO] * q_mid * q_mid * g_lam[k]


@njit(cache=True, nogil=True, inline='always')
def residual_norm(R):
    """Return |R|^2 for the line search; 1e300 when not finite."""
    rnorm = 0.0
    for k in range(R.shape[0]):
        rnorm += R[k] * R[k]
    if not math.isfinite(rnorm):
        rnorm = 1e300
    return rnorm


@njit(cache=True, nogil=True, inline='always')
def vehicle_jacobian_row(flags, Nd, P, st, Us, mb, rz, J):
    """
    Add the vehicle to the Newton matrix's diagonal at its slot ``rz`` (a held axial dof's).

    Its mass, replacing the slot's node mass, and the d/dU* of drag and ram; in paper_code the
    drag acts on every wall node and its d/dU* is left to the Newton iteration.
    """
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    J[rz, BW] += (mb - Nd[(rz - 1) // 3, N_MZZ]) / alpha
    if (flags & F_DRAG) and not (flags & F_CODE):
        J[rz, BW] += dt * P[P_CD] * P[P_RHO] * math.pi * st[T_RMAX] * st[T_RMAX] * abs(Us)
    if flags & F_JET:
        J[rz, BW] += dt * P[P_RHO] * max(st[T_VDOT], 0.0)


@njit(cache=True, nogil=True, inline='always')
def factorise_newton_matrix(flags, q1, vrel, Us, ts, E, Nd, P, st, body, rz, mb, K, C, J):
    """
    Assemble J = M/alpha - dt (alpha dt K + C) at (q*, v*) and factorise it (banded LU).

    Held dofs get identity rows and columns; the vehicle, when solved with the shell, takes a
    held slot ``rz``: by translation invariance dF/dU* = alpha dt K[:, rz] + C[:, rz], so the
    matrix stays banded.  Returns False when the factorisation fails.
    """
    n1 = Nd.shape[0]
    n = 3 * n1
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    assemble_KC(flags, q1, vrel, Us, ts, E, Nd, P, K, C)
    for k in range(n):
        for j in range(2 * BW + 1):
            J[k, j] = -dt * (alpha * dt * K[k, j] + C[k, j])
    for i in range(n1):
        J[3 * i, BW] += Nd[i, N_MRR] / alpha
        J[3 * i, BW + 1] += Nd[i, N_MRZ] / alpha
        J[3 * i + 1, BW - 1] += Nd[i, N_MRZ] / alpha
        J[3 * i + 1, BW] += Nd[i, N_MZZ] / alpha
        J[3 * i + 2, BW] += Nd[i, N_MTT] / alpha
    if body:
        vehicle_jacobian_row(flags, Nd, P, st, Us, mb, rz, J)
    for k in range(n):
        if fixed_dof(Nd, k) and not (body and k == rz):
            for j in range(2 * BW + 1):
                J[k, j] = 0.0
                kk = k + j - BW
                if 0 <= kk < n:
                    J[kk, k - kk + BW] = 0.0
            J[k, BW] = 1.0
    return band_lu(J, n, BW)


@njit(cache=True, nogil=True, inline='always')
def correction_coefficient(flags, st, P, J, wz, gf, zz, water, rho_lam_now, ring, ring_j, c):
    """
    Return the coefficient c of the rank-one part left out of the factorised J; refresh zz.

    Consistent coupling: the jet pressure's d(p)/dV' and the inertia of the water inside and of
    the forming ring, c g g^T with zz = J^-1 g (the ring's none in the step that crosses
    pinch-off: its impulse there follows the previous step's rate, not the unknowns).
    paper_code: the wall-borne thrust and refill force, dF = w (dT/dV') g^T, zz = J^-1 w.
    Otherwise ``c`` is returned unchanged.
    """
    rho_lam = water[0]
    kappa = ring[0]
    crossing = ring[4]
    dt = P[P_DT]
    n = gf.shape[0]
    if (flags & F_JET) and (flags & F_CODE):
        Aj = st[T_AOUT] if st[T_VDOT] < 0 else P[P_AIN]
        c = dt * 2.0 * P[P_CF] * P[P_RHO] * abs(st[T_VDOT]) / Aj
        band_solve(J, n, BW, wz, zz)
    elif ((flags & F_JET) and not (flags & F_PAPER)) or rho_lam > 0.0:
        ring_c = kappa if ring_j < 0.0 and not crossing else 0.0
        c = rank_one_coefficient(flags, st, P, dt, (rho_lam_now + ring_c) / P[P_ALPHA])
        band_solve(J, n, BW, gf, zz)
    return c


@njit(cache=True, nogil=True, inline='always')
def rank_one_correction(dv, gf, zz, c):
    """Turn dv = J^-1 R into (J + c u g^T)^-1 R, zz = J^-1 u (Sherman-Morrison)."""
    n = dv.shape[0]
    gy = 0.0
    gz = 0.0
    for k in range(n):
        gy += gf[k] * dv[k]
        gz += gf[k] * zz[k]
    fac = c * gy / (1.0 + c * gz)
    for k in range(n):
        dv[k] -= fac * zz[k]


@njit(cache=True, nogil=True, inline='always')
def newton_update(vs, dv):
    """Take v* -= dv; return (max |dv|, max |v*|, sum dv: not finite on a blow-up), m/s."""
    dmax = 0.0
    vmax = 0.0
    dsum = 0.0
    for k in range(vs.shape[0]):
        vs[k] -= dv[k]
        dsum += dv[k]
        if abs(dv[k]) > dmax:
            dmax = abs(dv[k])
        if abs(vs[k]) > vmax:
            vmax = abs(vs[k])
    return dmax, vmax, dsum


@njit(cache=True, nogil=True, inline='always')
def newton_solve(
    flags, state, qn, vn, U, Us, ts, amp_cmd, E, Nd, P, body, rz, have_lu, water, ring, w, J, ze
):
    """
    Solve the implicit step for the midpoint velocities ``vs`` (in place) by modified Newton.

    The factorised matrix ``J`` is reused across iterations and steps (``have_lu``) and
    refreshed when the contraction slows; the terms left out of its band (rank one or, with
    the water's momentum, rank three) are added by Sherman-Morrison / Woodbury; a step that
    raises |R| is halved (backtracking).  Returns (status, whether J may be reused).
    """
    F, gV, vrel, st, q1, v1, vs = w.F, w.gV, w.vrel, w.st, w.q1, w.v1, w.vs
    R, dv, zz, gf, K, C, e_u, wz = w.R, w.dv, w.zz, w.gf, w.K, w.C, w.e_u, w.wz
    q_end, g_end, g_lam = w.q_end, w.g_end, w.g_lam
    n = 3 * Nd.shape[0]
    tail = 2 * n
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    rho_lam, deforming, rho_s, q_start, lam_start = water
    rho_lam_now = rho_lam  # the Newton matrix's inertia of the water inside
    ring_j = 0.0
    mb = 0.0
    fresh = False
    prev = 1e300
    pcoef = 0.0
    rprev = 1e300
    lam = 1.0
    for it in range(2 * int(P[P_MAXIT])):
        if body:
            Us = vs[rz]
        node_positions(Nd, qn, vs, Us, alpha * dt, q1)
        forces(flags, q1, vs, Us, ts, amp_cmd, E, Nd, P, F, gV, vrel, st)
        shell_residual(Nd, vn, vs, F, P, R)
        free_rows(Nd, body, rz, gV, R, gf)
        if body:
            mb = vehicle_residual(flags, st, U, Us, P, rz, R)
        if rho_lam > 0.0:
            rho_lam_now = water_inside_residual(
                Nd, P, qn, vn, vs, U, Us, body, rz, water, rho_lam_now, gf, q_end, g_end, g_lam,
                v1, R,
            )
            if deforming:
                narrowing_pull(Nd, P, st, q1, body, rz, g_lam, R)
        if ring[0] > 0.0:
            ring_j, _, _ = ring_impulse(ring, Nd, P, st, qn, vn, vs, Us, U, body, q_end, g_end, v1)
            for k in range(n):
                R[k] += ring_j * gf[k]
            if body:
                R[rz] += ring[1] * ring_j  # the thrust A p_ex on the vehicle
        state[tail + S_NIT] += 1.0
        # backtracking line search on |R|: halve a Newton step that increased the residual
        rnorm = residual_norm(R)
        if rnorm > rprev and lam > 1.0 / 64.0:
            lam *= 0.5
            for k in range(n):
                vs[k] += lam * dv[k]
            continue
        if rnorm > rprev and not fresh:
            have_lu = False  # even short steps fail: the Jacobian is stale
        rprev = rnorm
        lam = 1.0
        if have_lu:
            # refresh the low-rank correction for the reused factorisation
            pcoef = correction_coefficient(
                flags, st, P, J, wz, gf, zz, water, rho_lam_now, ring, ring_j, pcoef
            )
        else:
            fresh = True
            state[tail + S_NJAC] += 1.0
            if not factorise_newton_matrix(
                flags, q1, vrel, Us, ts, E, Nd, P, st, body, rz, mb, K, C, J
            ):
                return ERR_NEWTON, have_lu
            if rho_s > 0.0 and body:
                e_u[rz] = 1.0
                band_solve(J, n, BW, e_u, ze)
            pcoef = correction_coefficient(
                flags, st, P, J, wz, gf, zz, water, rho_lam_now, ring, ring_j, 0.0
            )
            have_lu = True
        band_solve(J, n, BW, R, dv)
        if rho_s > 0.0 and body:
            _rank_three_correction(dv, gf, zz, ze, rz, pcoef, rho_s / alpha, n)
        elif pcoef > 0.0:
            rank_one_correction(dv, gf, zz, pcoef)
        dmax, vmax, dsum = newton_update(vs, dv)
        if not (math.isfinite(dsum) and math.isfinite(vmax)) or vmax > P[P_VLIM]:
            return ERR_NEWTON, have_lu
        if dmax <= P[P_TOL] * (vmax + P[P_VSCALE]):
            return OK, have_lu
        if (dmax > 0.3 * prev or it >= 6) and not fresh:
            have_lu = False  # slow contraction: refresh the Jacobian
        prev = dmax
    return ERR_NEWTON, have_lu


@njit(cache=True, nogil=True, inline='always')
def jet_without_wall_pressure(flags, state, tail, st, P, po):
    """
    Book the jet's kinetic energy that no cavity pressure paid for (paper and paper_code).

    On outflow the consistent wall pressure would have charged the shell the jet's kinetic energy
    flux in the body frame, 1/2 rho A u^3: it is created (docs/theory/shell.md, "The ledger of
    the paper coupling").  On inflow nothing is created (no suction acts on the wall) and the
    inflow jet's kinetic energy is not booked out either: returns ``po`` (W) less it.
    """
    dt = P[P_DT]
    if (flags & F_JET) and st[T_VDOT] < 0.0:
        uj_ = -st[T_VDOT] / st[T_AOUT]
        state[tail + S_CREATED] += dt * 0.5 * P[P_RHO] * st[T_AOUT] * uj_ * uj_ * uj_
    elif flags & F_JET:
        uin_ = st[T_VDOT] / P[P_AIN]
        po -= 0.5 * P[P_RHO] * P[P_AIN] * uin_ * uin_ * uin_
    return po


@njit(cache=True, nogil=True, inline='always')
def paper_vehicle_step(flags, state, Nd, P, st, qn, vn, vs, U, Us, water, q_end, g_end, v1):
    """
    Paper coupling: the vehicle after the shell's converged step, and the step's ledger.

    The water inside's momentum changes by rho S (Q_end - Q_start) over the step, Q relative to
    the body (the frame the paper's shell lives in); no wall force reacts to it, so its work on
    the vehicle is created or destroyed (docs/theory/shell.md).  Returns (U* in m/s and the
    vehicle's acceleration, thrust, drag, jet and other powers: ``body_terms`` at U*).
    """
    rho_s = water[2]
    q_start = water[3]
    tail = 6 * Nd.shape[0]
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    imp_mom = 0.0
    if rho_s > 0.0:
        q_end_flow = end_of_step_flow(Nd, qn, vn, vs, 0.0, 0.0, dt, alpha, q_end, g_end, v1)
        imp_mom = rho_s * (q_end_flow - q_start)
    if flags & F_BODY:
        Us = _paper_vehicle_midpoint(flags, st, U, alpha, dt, P, imp_mom)
        state[tail + S_CREATED_MOM] -= imp_mom * Us
    acc_b, thr, dr, ram, pj, po, mb = body_terms(flags, st, Us, P)
    po = jet_without_wall_pressure(flags, state, tail, st, P, po)
    return Us, acc_b, thr, dr, pj, po


@njit(cache=True, nogil=True, inline='always')
def ring_on_vehicle(ring, state, Nd, P, st, qn, vn, vs, Us, U, body, mb, q_end, g_end, v1):
    """
    jet.starting_jet, the converged step: the exit over-pressure p_ex on the vehicle and its work.

    The vehicle feels A p_ex; the jet carries A p_ex (u_j - U) out (the wall paid A p_ex u_j
    through grad V); midpoint quantities, so the ledger keeps the integrator's closure order.
    Returns (p_ex in Pa, the thrust's, vehicle acceleration's and jet power's increments, the
    outflow rise in m^3/s, the end volume rate in m^3/s).
    """
    area = ring[1]
    dt = P[P_DT]
    ring_j, ring_rise, ring_q1 = ring_impulse(
        ring, Nd, P, st, qn, vn, vs, Us, U, body, q_end, g_end, v1
    )
    ring_pex = -ring_j / dt
    ring_out = ring_j * (st[T_VDOT] + area * (Us if body else 0.0)) / dt
    dacc = area * ring_pex / mb if body else 0.0
    state[6 * Nd.shape[0] + S_OVERPRESSURE_WORK] += dt * ring_out
    return ring_pex, area * ring_pex, dacc, ring_out, ring_rise, ring_q1


@njit(cache=True, nogil=True, inline='always')
def end_velocities(Nd, vn, vs, alpha, v1):
    """Fill v1 with the theta-scheme's end velocities v_n + (v* - v_n)/alpha; held dofs 0."""
    for k in range(vn.shape[0]):
        v1[k] = 0.0 if fixed_dof(Nd, k) else vn[k] + (vs[k] - vn[k]) / alpha


@njit(cache=True, nogil=True, inline='always')
def implicit_step(
    flags, state, qn, vn, U, t, amp_cmd, E, Nd, P, body, rz, have_lu, rho_lam, deforming, rho_s,
    w, J, vprev, ze, ws,
):
    """
    One step of the implicit theta-scheme from (``qn``, ``vn``, U) to (``q1``, ``v1``).

    v* at q* = q_n + alpha dt v*_rel, M (v* - v_n)/alpha = dt F(q*, v*); alpha = 1/2 implicit
    midpoint, 1 backward Euler.  The vehicle's midpoint speed U* is predicted
    (U* = U_n + alpha dt a_n) and, in the consistent coupling (``body``), solved together with
    the shell in the slot ``rz``; the paper coupling's is solved after the shell.  Returns
    (status, the vehicle's end and midpoint speeds in m/s, its acceleration in m/s^2, thrust and
    body drag in N, cavity pressure in Pa, volume in m^3, volume rate in m^3/s, whether ``J``
    holds a reusable factorisation).
    """
    F, gV, vrel, st, q1, v1, vs = w.F, w.gV, w.vrel, w.st, w.q1, w.v1, w.vs
    q_end, g_end, g_lam = w.q_end, w.g_end, w.g_lam
    n1 = Nd.shape[0]
    tail = 6 * n1
    dt = P[P_DT]
    alpha = P[P_ALPHA]
    Us = U + alpha * dt * state[tail + S_A]
    if not body:
        Us = 0.0
    ts = t + alpha * dt
    predict_velocities(vn, vprev, alpha, ws[WS_HAVE_PREV] > 0.5, vs)
    ws[WS_HAVE_PREV] = 1.0
    vs[rz] = Us
    u_frame = U if body else 0.0
    q_start, lam_start = water_inside_at_start(
        Nd, qn, vn, u_frame, rho_lam, deforming, P[P_LAMBDA], g_end, g_lam
    )
    water = (rho_lam, deforming, rho_s, q_start, lam_start)
    ring = ring_at_start(flags, state, Nd, qn, vn, u_frame, P, g_end)
    code, have_lu = newton_solve(
        flags, state, qn, vn, U, Us, ts, amp_cmd, E, Nd, P, body, rz, have_lu, water, ring, w, J,
        ze,
    )
    if code != OK:
        return code, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, have_lu
    # the converged step: the forces at its midpoint, then the vehicle and the ledger
    if body:
        Us = vs[rz]
    node_positions(Nd, qn, vs, Us, alpha * dt, q1)
    forces(flags, q1, vs, Us, ts, amp_cmd, E, Nd, P, F, gV, vrel, st)
    Ush = Us  # the frame speed the shell's kinematics use (0 in the paper coupling)
    ring_pex = 0.0
    ring_rise = 0.0  # the step's outflow rise beyond the pulse's peak, m^3/s
    ring_q1 = 0.0  # the converged step's end volume rate (while forming), m^3/s
    if flags & F_PAPER:
        Us, acc_b, thr, dr, pj, po = paper_vehicle_step(
            flags, state, Nd, P, st, qn, vn, vs, U, Us, water, q_end, g_end, v1
        )
    else:
        acc_b, thr, dr, ram, pj, po, mb = body_terms(flags, st, Us, P)
        if ring[0] > 0.0:
            ring_pex, dthr, dacc, dpj, ring_rise, ring_q1 = ring_on_vehicle(
                ring, state, Nd, P, st, qn, vn, vs, Us, U, body, mb, q_end, g_end, v1
            )
            thr += dthr
            if body:
                acc_b += dacc
            pj += dpj
        if flags & F_CODE:
            # as in the paper coupling no cavity pressure pays for the jet; and the thrust, the
            # refill force and the drag work at the wall's speed, not the vehicle's
            # (docs/validation/papers.md)
            po = jet_without_wall_pressure(flags, state, tail, st, P, po)
            state[tail + S_CREATED_WALL] += dt * (
                (thr + dr) * st[T_WREL] + st[T_FREF] * (Us + st[T_WREL])
            )
    node_positions(Nd, qn, vs, Ush, dt, q1)
    end_velocities(Nd, vn, vs, alpha, v1)
    U1 = U + (Us - U) / alpha
    code = _check(q1, v1, n1, P)
    if code != OK:
        return code, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, have_lu
    if deforming and folded(q1, n1):
        # the section is no longer a function of z: the 1-D internal flow is undefined
        return ERR_FOLD, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, have_lu
    state[tail + S_IN] += dt * st[T_PACT]
    state[tail + S_VISC] += dt * st[T_PVISC]
    state[tail + S_DRAG] += dt * (st[T_PDRAG] - dr * Us)
    state[tail + S_JET] += dt * pj
    state[tail + S_OTHER] += dt * (po + st[T_PCONT])
    pres, vol, vdot = st[T_P], st[T_VOL], st[T_VDOT]
    if P[P_FORMATION_NUMBER] > 0.0:
        pres += ring_pex
        # the pulse's running peak (kept past pinch-off: ring_q1 = 0 there), reset with T*
        state[tail + S_PEAK_OUTFLOW] = sj.next_peak_outflow(ring[3], vdot, ring_q1, ring_rise)
        state[tail + S_LAST_RISE] = ring_rise
        state[tail + S_FORMATION_TIME] = sj.next_formation_time(
            state[tail + S_FORMATION_TIME], vdot, st[T_AOUT], dt
        )
    return OK, U1, Us, acc_b, thr, dr, pres, vol, vdot, have_lu


@njit(cache=True, nogil=True, inline='always')
def commit_step(flags, state, P, st, q1, v1, x, t, U1, Uh, acc_b, thr, dr, pres, vol, vdot):
    """Write the step that passed its checks into ``state``: shell, vehicle, observed stats."""
    n = q1.shape[0]
    tail = 2 * n
    dt = P[P_DT]
    if not (flags & F_BODY):
        U1 = 0.0
        Uh = 0.0
        acc_b = 0.0
    for k in range(n):
        state[k] = q1[k]
        state[n + k] = v1[k]
    state[tail + S_X] = x + dt * Uh
    state[tail + S_U] = U1
    state[tail + S_A] = acc_b
    state[tail + S_THR] = thr
    state[tail + S_BDRAG] = dr
    state[tail + S_P] = pres
    state[tail + S_VOL] = vol
    state[tail + S_VDOT] = vdot
    state[tail + S_TIME] = t + dt
    if flags & F_JET:
        state[tail + S_UJ] = -vdot / (st[T_AOUT] if vdot < 0 else P[P_AIN])


@njit(cache=True, nogil=True)
def _advance_impl(flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme, J, vprev, ze, ws):
    """
    Advance ``state`` by ``n_steps`` (see ``advance``) with the Newton workspace given.

    The workspace: ``J`` the factorised Newton matrix, ``vprev`` the predictor's previous
    velocities, ``ze`` = J^-1 of the vehicle's unit row, ``ws[WS_HAVE_LU]`` (1: ``J`` holds a
    factorisation that may be reused) and ``ws[WS_HAVE_PREV]`` (1: ``vprev`` holds the velocities
    at the start of the previous step).  Fresh zeros give exactly the per-call behaviour; passing
    the workspace a previous call left behind continues that call's modified Newton (its
    factorisation and predictor) as if the two calls were one.
    """
    n1 = Nd.shape[0]
    n = 3 * n1
    tail = 6 * n1
    dt = P[P_DT]
    qn = np.empty(n)
    vn = np.empty(n)
    wz = np.zeros(n)  # paper_code: the axial load's weights (area shares), rank-one Jacobian term
    # the vehicle's slot in the implicit system: the clamped ring's axial dof (paper_code: the
    # clamped rim's); solved with the shell only in the consistent coupling (and paper_code)
    rz = 3 * (n1 - 1) + 1
    if flags & F_CODE:
        rz = 3 * code_rim(Nd) + 1
        for i in range(rz // 3, n1):
            wz[3 * i + 1] = Nd[i, N_WWALL]
    body = (flags & F_BODY) != 0 and (flags & F_PAPER) == 0
    # the factorised Newton matrix is reused across steps (modified Newton) and, with a kept
    # workspace, across calls
    have_lu = ws[WS_HAVE_LU] > 0.5
    # the water inside: 1/2 rho Lambda Q^2 with Q = grad V . v_rel (docs/theory/shell.md, the
    # water inside), Lambda following the shape when deforming; its momentum relative to the body
    # rho S Q along +z
    rho_lam = P[P_RHO] * P[P_LAMBDA]
    deforming = rho_lam > 0.0 and P[P_LAMBDA_DEFORMING] > 0.5
    rho_s = P[P_RHO] * P[P_SMOM]
    w = StepWork(
        np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(N_STATS), np.zeros(n),  # F gV vrel st acc
        np.empty(n), np.empty(n), np.empty(n),  # q1 v1 vs
        np.empty(n), np.empty(n), np.empty(n), np.empty(n),  # R dv zz gf
        np.zeros((n, 2 * BW + 1)), np.zeros((n, 2 * BW + 1)),  # K C
        np.zeros(n),  # e_u: the vehicle's unit row (J^-1 of it: ze, consistent coupling)
        wz, np.zeros(n), np.zeros(n), np.zeros(n),  # wz q_end g_end g_lam
    )
    for step in range(n_steps):
        t = time0 + step * dt
        for k in range(n):
            qn[k] = state[k]
            vn[k] = state[n + k]
        U = state[tail + S_U]
        if not (flags & F_BODY):
            U = 0.0
        x = state[tail + S_X]
        if scheme == 0:
            code, U1, Uh, acc_b, thr, dr, pres, vol, vdot = verlet_step(
                flags, state, qn, vn, U, t, amp_cmd, E, Nd, P, w
            )
        else:
            code, U1, Uh, acc_b, thr, dr, pres, vol, vdot, have_lu = implicit_step(
                flags, state, qn, vn, U, t, amp_cmd, E, Nd, P, body, rz, have_lu, rho_lam,
                deforming, rho_s, w, J, vprev, ze, ws,
            )
        if code != OK:
            return step, code
        commit_step(
            flags, state, P, w.st, w.q1, w.v1, x, t, U1, Uh, acc_b, thr, dr, pres, vol, vdot
        )
        ws[WS_HAVE_LU] = 1.0 if have_lu else 0.0
    return n_steps, OK


@njit(cache=True, nogil=True)
def advance(flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme):
    """
    Advance ``state`` in place by ``n_steps``; returns (steps done, status code).

    The state is only written after a step passed its checks, so it is left at the last good step.
    ``flags`` is a runtime value here: one compilation (~20 s, cached on disk) serves every scene.
    """
    n = 3 * Nd.shape[0]
    return _advance_impl(
        flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme,
        np.zeros((n, 2 * BW + 1)), np.empty(n), np.zeros(n), np.zeros(WS_LEN),
    )


def workspace_length(n1, n_state):
    """Length of ``advance_kept``'s workspace vector for ``n1`` nodes and a state of n_state."""
    return WS_LEN + 6 * n1 + n_state + N_PARAMS


@njit(cache=True, nogil=True)
def advance_kept(flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme, J, W):
    """
    Advance like ``advance``, continuing the Newton workspace of the previous call.

    ``J`` (the factorised Newton matrix) and ``W`` = [flags (WS_LEN) | predictor history (3 n1) |
    J^-1 of the vehicle row (3 n1) | the state the last call left | the parameters it ran with]
    are owned by the caller (``workspace_length``) and updated in place.  The factorisation and
    the predictor carry over only when this call continues the last one: the state bit for bit
    the one it left and the same parameters (the step among them); otherwise, and after a failed
    step, the solve starts afresh.  Calls that continue one another thus give the bits of one call
    over all their steps.  The check and the bookkeeping run here, not in Python, to keep the
    per-call cost of a 10 ms publication period small.
    """
    n = 3 * Nd.shape[0]
    ns = state.size
    o_prev = WS_LEN
    o_ze = o_prev + n
    o_snap = o_ze + n
    o_par = o_snap + ns
    same = True
    for k in range(ns):
        if state[k] != W[o_snap + k]:
            same = False
            break
    if same:
        for k in range(P.size):
            if P[k] != W[o_par + k]:
                same = False
                break
    if not same:
        for k in range(WS_LEN):
            W[k] = 0.0
        for k in range(P.size):
            W[o_par + k] = P[k]
    done, code = _advance_impl(
        flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme, J,
        W[o_prev:o_ze], W[o_ze:o_snap], W[:WS_LEN],
    )
    if code != OK:
        for k in range(WS_LEN):
            W[k] = 0.0
    for k in range(ns):
        W[o_snap + k] = state[k]
    return done, code


@njit(cache=True, nogil=True)
def advance_specialised(flags, state, time0, n_steps, amp_cmd, E, Nd, P, scheme):
    """
    Advance like ``advance``, with ``flags`` forced to a compile-time literal.

    Same as ``advance`` with ``flags`` forced to a compile-time literal: the switched-off terms
    are compiled out (measured +15-40 % speed on the robot scene) at the price of one ~20 s
    compilation per distinct flag set (cached on disk).  Selected by
    ``simulation.specialise_kernel: true``.
    """
    n = 3 * Nd.shape[0]
    return _advance_impl(
        literally(flags), state, time0, n_steps, amp_cmd, E, Nd, P, scheme,
        np.zeros((n, 2 * BW + 1)), np.empty(n), np.zeros(n), np.zeros(WS_LEN),
    )


@njit(cache=True, nogil=True)
def cavity_volume(q, n1):
    """Cavity volume, m^3: ``volume_grad``'s V by the same operations (same bits), no gradient."""
    V = 0.0
    for e in range(n1 - 1):
        ra = q[3 * e]
        za = q[3 * e + 1]
        rb = q[3 * e + 3]
        zb = q[3 * e + 4]
        S = ra * ra + ra * rb + rb * rb
        dz = za - zb
        V += math.pi / 3.0 * S * dz
    return V


@njit(cache=True, nogil=True)
def evaluate(flags, state, t, amp_cmd, E, Nd, P):
    """Stats at the stored state (energy, volume, ...) for observation and the ledger."""
    n1 = Nd.shape[0]
    n = 3 * n1
    F = np.zeros(n)
    gV = np.zeros(n)
    vrel = np.zeros(n)
    st = np.zeros(N_STATS)
    U = state[6 * n1 + S_U]
    Ush = 0.0 if flags & F_PAPER else U  # the paper coupling's shell lives in the body frame
    forces(flags, state[:n], state[n:2 * n], Ush, t, amp_cmd, E, Nd, P, F, gV, vrel, st)
    ksh, kveh, kint = kinetic(Nd, state[n:2 * n], U, P, st[T_VOL], flags)
    return st, ksh, kveh, kint


@njit(cache=True, nogil=True)
def stiffness_damping(flags, state, t, E, Nd, P):
    """Banded K and C at the stored state (for the stable-step estimate)."""
    n1 = Nd.shape[0]
    n = 3 * n1
    F = np.zeros(n)
    gV = np.zeros(n)
    vrel = np.zeros(n)
    st = np.zeros(N_STATS)
    U = 0.0 if flags & F_PAPER else state[6 * n1 + S_U]
    forces(flags, state[:n], state[n:2 * n], U, t, 0.0, E, Nd, P, F, gV, vrel, st)
    K = np.zeros((n, 2 * BW + 1))
    C = np.zeros((n, 2 * BW + 1))
    assemble_KC(flags, state[:n], vrel, U, t, E, Nd, P, K, C)
    return K, C


# numba keys this file's cache on this file alone: drop it when a module compiled in changes
drop_stale_cache(advance, (sj, cable_pulse))
