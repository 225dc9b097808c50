"""
Numba kernels that advance N lumped robots in one call (the vector environment's engine).

Same physics, same arithmetic (``exact=True``): the right-hand side below is
``lumped.kernels.rhs`` written for a block of robots (the same expressions in the same order,
specialised on the same literal term flags), and the step is ``lumped.kernels._advance``'s RK4
step (same stage sums, same valve stroke, same bound checks ``_check``). Only the order of the
loops differs: robots are innermost inside each RK stage, so that LLVM vectorises the stage over
robots (AVX2: 4 robots per instruction).

Layout, as seen by LLVM: the robots are cut into blocks of ``BLOCK`` robots (the last block padded
with copies of a real robot, never written back); a block's states, RK stage values, stage sums and
hoisted per-robot parameters live in one flat work array at compile-time-constant offsets
(``row * BLOCK + j``), so that every stage loop has a constant trip count and provably disjoint
accesses (no runtime alias checks, no scalar fallback). Data-dependent ``if``s of the single-robot
code (valve sealed or open, pump relief, jet in or out, ...) are branch-free selects of values that
are both computed, which gives the same value as the branch; the untaken side may divide by zero
(``error_model='numpy'``: it gives inf or nan and is discarded, never raises).

Transcendental functions: Lamb's added mass needs ``atanh(e)`` four times a step, and libm's atanh
is a scalar call (about 27 ns) that LLVM cannot vectorise. It is evaluated in its own pass over the
block: ``exact=True`` calls ``math.atanh`` (libm), and the batch then equals N single-robot runs
bit for bit (tested); ``exact=False`` uses ``_atanh_fast``, fdlibm's log1p algorithm written
branch-free (polynomial of Sun Microsystems' e_log/s_log1p, the exponent split by integer bit
operations), which vectorises. Its error is at most 1.65 ulp on 3.5e6 inputs against an
extended-precision reference (libm: the same; tested), like libm's own. ``exact=False`` also
compiles the step with the LLVM flags ``FAST_MATH`` (a shared reciprocal for divisions by the same
value, fused multiply-adds), each a rounding difference of about an ulp. The batch then differs
from single-robot runs only by rounding, a relative 1e-16 per operation that the (damped,
non-chaotic) dynamics carry to below 1e-12 of each state component's scale over thousands of steps
(tested at that tolerance). The two paths are two compiled copies of one Python body
(``_advance_batch_exact`` and ``_advance_batch_fast``): fastmath is a per-function flag.

Steps that the vector path does not take: a robot whose step needs RK4 stability sub-steps
(``rate * dt > 1.5``: a throttled fast flow or a stiff light shell) or whose valve seals a moving
flow this step is advanced by ``lumped.kernels._advance`` itself for that one step (exactly the
single-robot step; rare). A robot whose step fails keeps its last good state, gets a non-zero
``status`` (lumped.kernels.ERR_*) and is skipped by later calls until the caller resets it
(``status[i] = OK``); ``done[i]`` counts the steps it made, as in ``_advance``.

Arrays: states ``Y`` (N, NY) and parameters ``P`` (N, NP), C-contiguous, one row per robot;
commands ``q_cmd`` and ``valve_cmd`` (N,).

``flags | LOSSES_OFF`` integrates the state and the pump's work only, not the ledger's loss and
correction integrals: they feed nothing back, and a learner's rewards (distance, speed, cost of
transport) need none of them. LLVM then drops their expressions: 14-28 % more robot-steps/s
(benchmarks/results/envs.md, N >= 64).
The state and the pump's work agree with the single-robot runs as above (the fast path tested to
1e-12 of each component's scale); the loss components keep the caller's values.
"""

from __future__ import annotations

import math
import types as types_module

from llvmlite import ir
from numba import literally, njit, types
from numba.extending import intrinsic
import numpy as np
from pulsejet_sim.core import model_io
from pulsejet_sim.core.kernel_cache import drop_stale_cache
from pulsejet_sim.models.lumped import kernels as K

# LLVM flags of the default (exact=False) path: 'arcp' lets it multiply by one reciprocal where
# rhs divides several values by the same one (v_b, a_n, the masses), 'contract' fuses a multiply
# and an add, 'nsz' ignores the sign of zero. Each changes a result by at most about an ulp. Not
# 'nnan'/'ninf' (the step's finiteness check must see nan and inf) nor 'reassoc'/'afn' (they
# would undo fdlibm's compensated sums in _atanh_fast).
FAST_MATH = {'arcp', 'contract', 'nsz'}
# FAST_MATH applies to the fast copy's own body and what is inlined into it (the stages, rhs,
# the spheroid, _atanh_fast), never to the compiled helpers it calls: each says fastmath=False,
# or it would inherit the flags of whichever copy compiled it first (see lumped.kernels)

# a bit of the batch kernel's literal flags, above lumped.kernels' bits (which ignore it):
# integrate the state and the pump's work only, not the ledger's losses and corrections
# (Y_E_JET..Y_C_RAM), which nothing in the state depends on; they keep the caller's values
LOSSES_OFF = 1 << 30
N_LOSSES_OFF = K.Y_W_PUMP + 1  # components integrated with LOSSES_OFF
BLOCK = 64  # robots per block (a multiple of the SIMD width; the block's rows stay in L1/L2)
# a last block with fewer robots runs them one at a time (lumped.kernels._advance)
SCALAR_BELOW = 16

# ---- rows of a block's work array (each BLOCK long) ---------------------------------------------
R_Y = 0  # committed state, K.NY rows (component c at R_Y + c)
R_ACC = R_Y + K.NY  # RK4 stage sum k1 + 2 k2 + 2 k3 + k4 of the integrated components
R_TU = R_ACC + K.N_INTEGRATED  # stage state (the components that rhs reads)
R_TB = R_TU + 1
R_TW = R_TU + 2
R_TQ = R_TU + 3
R_E2 = R_TU + 4  # e^2 = 1 - (b/a)^2 and e of the spheroid at the stage's b
R_E = R_TU + 5
R_G = R_TU + 6  # atanh(e)
R_SLOW = R_TU + 7  # 1: the step is taken by lumped.kernels._advance (sub-steps or sealing)
R_ACTIVE = R_TU + 8  # 1: a real robot still advancing
R_DONE = R_TU + 9
R_STATUS = R_TU + 10
R_Q = R_TU + 11  # commands
R_V = R_TU + 12
# per-robot parameters and constant sub-expressions of rhs (each computed as rhs computes it)
R_RHO = R_TU + 13
R_A = R_RHO + 1
R_K = R_RHO + 2
R_B0 = R_RHO + 3
R_RELIEF = R_RHO + 4
R_STALL = R_RHO + 5
R_TAU = R_RHO + 6
R_A_N = R_RHO + 7
R_C_A = R_RHO + 8  # 8/3 pi a
R_M_SHELL = R_RHO + 9
R_INERTANCE = R_RHO + 10  # rho L_n / A_n
R_LAM = R_RHO + 11  # 32 mu L_n / d_n^2
R_K_INLET = R_RHO + 12
R_M_SOLID = R_RHO + 13
R_V_SOLID = R_RHO + 14
R_CD = R_RHO + 15
R_C1 = R_RHO + 16
R_VOL_COEF = R_RHO + 17  # rho 4/3 pi a (Lamb's added mass)
R_B_MIN = R_RHO + 18
R_B_MAX = R_RHO + 19
R_U_MAX = R_RHO + 20
R_STROKE = R_RHO + 21  # valve stroke per step, valve_rate dt
R_CONTRACTION = R_RHO + 22  # the valve's 1/opening - 1 over the step
R_SEAL = R_RHO + 23  # 1: the valve seals a moving flow at the end of the step
NROWS = R_RHO + 24

# fdlibm (Sun Microsystems, e_log.c / s_log1p.c) constants
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LP1 = 6.666666666666735130e-01
_LP2 = 3.999999999940941908e-01
_LP3 = 2.857142874366239149e-01
_LP4 = 2.222219843214978396e-01
_LP5 = 1.818357216161805012e-01
_LP6 = 1.531383769920937332e-01
_LP7 = 1.479819860511658591e-01


@intrinsic
def _f2i(typingctx, x):
    """Return the bits of a float64 as an int64 (an LLVM bitcast: vectorises)."""
    if isinstance(x, types.Float) and x.bitwidth == 64:

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], ir.IntType(64))

        return types.int64(x), codegen
    return None


@intrinsic
def _i2f(typingctx, i):
    """Return the float64 with these bits."""
    if isinstance(i, types.Integer) and i.bitwidth == 64:

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], ir.DoubleType())

        return types.float64(i), codegen
    return None


@njit(cache=True, inline='always', error_model='numpy')
def _log1p_pos(x):
    """
    Return log(1 + x) for finite x >= 0 without branches.

    fdlibm's s_log1p: its k = 0 path below 0.41422, the exponent split with a rounding correction
    above; the |f| < 2^-20 shortcut is not needed for accuracy and is left out.
    """
    small = x < 0.41421356237309503
    u = 1.0 + x
    bits = _f2i(u)
    hu = bits >> 32
    k = (hu >> 20) - 1023
    c = ((1.0 - (u - x)) if k > 0 else (x - (u - 1.0))) / u
    hm = hu & 0x000FFFFF
    big = hm >= 0x6A09E
    # normalise u to [sqrt(2)/2, sqrt(2)): high word hm | 0x3ff00000, or hm | 0x3fe00000 and k + 1
    hnew = hm | (0x3FE00000 if big else 0x3FF00000)
    k = k + 1 if big else k
    un = _i2f((hnew << 32) | (bits & 0xFFFFFFFF))
    f = un - 1.0
    if small:
        f = x
        c = 0.0
        k = 0
    hfsq = 0.5 * f * f
    s = f / (2.0 + f)
    z = s * s
    r = z * (_LP1 + z * (_LP2 + z * (_LP3 + z * (_LP4 + z * (_LP5 + z * (_LP6 + z * _LP7))))))
    dk = float(k)
    return dk * _LN2_HI - ((hfsq - (s * (hfsq + r) + (dk * _LN2_LO + c))) - f)


@njit(cache=True, inline='always', error_model='numpy')
def _atanh_fast(x):
    """
    Return atanh(x) for x in [0, 1] (and nan for nan or x > 1, inf at 1), as libm.

    glibc's e_atanh split (0.5 log1p(2x + 2x^2/(1-x)) below 0.5, 0.5 log1p(2x/(1-x)) above) over
    a vectorisable log1p.
    """
    t = x + x
    low = x < 0.5
    q = (t * x if low else t) / (1.0 - x)
    arg = t + q if low else q
    ok = x < 1.0  # false for nan and x >= 1
    r = 0.5 * _log1p_pos(arg if ok else 0.0)
    if not ok:
        r = math.inf if x == 1.0 else math.nan
    return r


@njit(cache=True, error_model='numpy', fastmath=False)
def atanh_fast(x):
    """_atanh_fast over an array (for tests)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = _atanh_fast(x[i])
    return out


@njit(cache=True, inline='always', error_model='numpy')
def _exact_added_mass(flags):
    return (
        flags & (K.T_ADDED_MASS | K.T_ADDED_MASS_VARIATION)
    ) and not flags & K.O_ADDED_MASS_SIMPLIFIED


@njit(cache=True, inline='always', error_model='numpy')
def _rhs(flags, W, j, u, b, w, q_p):
    """
    Compute lumped.kernels.rhs for robot j of the block at the stage state (u, b, w, q_p).

    Branch-free; returns the 16 derivatives and (damping rate, spring rate) of the diagnostics.
    ``x ** 2`` is written ``x * x`` and max(a, b) as its select: the values numba computes for them
    (its integer power and max are calls that stop LLVM's loop vectoriser).
    """
    B = BLOCK
    rho = W[R_RHO * B + j]
    valve = W[(R_Y + K.Y_VALVE) * B + j]
    q_cmd = W[R_Q * B + j]
    c_a = W[R_C_A * B + j]
    k = W[R_K * B + j]
    b0 = W[R_B0 * B + j]
    v_b = c_a * b
    # pump pressure-flow curve
    p_el = k * (b - b0) / v_b
    relief = W[R_RELIEF * B + j]
    stall = W[R_STALL * B + j]
    frac = (stall - p_el) / (stall - relief)
    q_relief = q_cmd * (frac if frac > 0.0 else 0.0)  # max(0.0, frac) as numba computes it
    q_target = q_relief if (q_cmd > 0.0 and p_el > relief) else q_cmd
    dq_p = (q_target - q_p) / W[R_TAU * B + j]
    volume = c_a * b * b / 2.0
    a_n = W[R_A_N * B + j]

    m_shell = W[R_M_SHELL * B + j]
    inertance = W[R_INERTANCE * B + j]
    m_l = inertance * v_b * v_b

    # outer flow (lumped.kernels.added_mass)
    m_x = 0.0
    dmx_db = 0.0
    if flags & (K.T_ADDED_MASS | K.T_ADDED_MASS_VARIATION):
        a = W[R_A * B + j]
        vol_coef = W[R_VOL_COEF * B + j]
        if flags & K.O_ADDED_MASS_SIMPLIFIED:
            c = W[R_C1 * B + j] * rho * 4.0 / 3.0 * math.pi
            m_x = c * (b * (b * b))  # b ** 3 as numba's integer power computes it
            dmx_db = 3.0 * c * (b * b)
        else:
            e2 = W[R_E2 * B + j]
            e = W[R_E * B + j]
            g = W[R_G * B + j] - e
            alpha0 = 2.0 * (1.0 - e2) / (e2 * e) * g
            dalpha_de = 2.0 * g * (-2.0 / e2 - 3.0 * (1.0 - e2) / (e2 * e2)) + 2.0 / e
            de_db = -b / (a * a * e)
            k1 = alpha0 / (2.0 - alpha0)
            two_m = 2.0 - alpha0
            dk1_db = 2.0 / (two_m * two_m) * dalpha_de * de_db
            m_x = k1 * vol_coef * b * b
            dmx_db = vol_coef * (dk1_db * b * b + 2.0 * k1 * b)
    k_x = 0.0
    f_kx = 0.0
    if flags & K.T_FLUID_STIFFNESS:
        a = W[R_A * B + j]
        q = 0.5 * rho * u * u
        s = 1.0 + b / (2.0 * a)
        dcp = 2.0 * (s * s - 1.0)
        ddcp_db = 2.0 * s / a
        k_x = q * 2.0 * math.pi * a * (dcp + b * ddcp_db)
        if not flags & K.O_COUPLING_CONSISTENT:
            f_kx = k_x * b
    reaction_ref = 0.0
    if flags & K.T_ADDED_MASS_VARIATION:
        reaction_ref = 0.5 * dmx_db * u * u
    reaction = 0.0
    if flags & K.O_COUPLING_CONSISTENT:
        if flags & K.T_FLUID_STIFFNESS:
            reaction = reaction_ref

    # valve shut (sealed) and open, both computed; the valve opening selects
    sealed = valve <= 0.0
    dw_s = (dq_p - c_a * w * w) / v_b
    p_cav_s = (m_shell * dw_s + k * (b - b0) + f_kx - reaction) / v_b

    q_n_o = q_p - v_b * w
    u_n = q_n_o / a_n
    sgn = 1.0 if u_n >= 0.0 else -1.0
    dp_visc_o = 0.0
    dpdq = 0.0
    if flags & K.T_VISCOUS_LOSS:
        lam = W[R_LAM * B + j]
        k_inlet = W[R_K_INLET * B + j]
        dp_visc_o = lam * u_n + sgn * 0.5 * rho * k_inlet * u_n * u_n
        dpdq += (lam + rho * k_inlet * abs(u_n)) / a_n
    contraction = W[R_CONTRACTION * B + j]  # 1.0 / valve - 1.0 (constant over the step)
    dp_valve_o = sgn * 0.5 * rho * contraction * contraction * u_n * u_n
    dpdq += rho * contraction * contraction * abs(u_n) / a_n
    dp_jet_ref_o = sgn * 0.5 * rho * u_n * u_n
    dp_jet = 0.0
    convective = 0.0
    c_jet_o = 0.0
    c_nozzle_o = 0.0
    if flags & K.O_COUPLING_CONSISTENT:
        dp_jet = dp_jet_ref_o
        dpdq += rho * abs(u_n) / a_n
        convective = c_a * w * w
    else:
        c_jet_o = -v_b * dp_jet_ref_o * w
        c_nozzle_o = inertance * v_b * c_a * w * w * w
    dp_n = dp_visc_o + dp_valve_o + dp_jet
    m_b_total_o = m_shell + m_l
    force = -k * (b - b0) - f_kx + reaction + v_b * dp_n + inertance * v_b * (dq_p - convective)
    dw_o = force / m_b_total_o
    dq_n = dq_p - c_a * w * w - v_b * dw_o
    p_cav_o = dp_visc_o + dp_valve_o + dp_jet_ref_o + inertance * dq_n
    damping_rate_o = v_b * v_b * dpdq / m_b_total_o

    q_n = 0.0 if sealed else q_n_o
    dw = dw_s if sealed else dw_o
    p_cav = p_cav_s if sealed else p_cav_o
    dp_visc = 0.0 if sealed else dp_visc_o
    dp_valve = 0.0 if sealed else dp_valve_o
    dp_jet_ref = 0.0 if sealed else dp_jet_ref_o
    m_b_total = m_shell if sealed else m_b_total_o
    damping_rate = 0.0 if sealed else damping_rate_o
    c_jet = 0.0 if sealed else c_jet_o
    c_nozzle = 0.0 if sealed else c_nozzle_o
    spring = k
    if not flags & K.O_COUPLING_CONSISTENT:
        spring += k_x

    # vehicle
    m_vehicle = W[R_M_SOLID * B + j]
    if flags & K.T_FLUID_MASS:
        m_vehicle += rho * (volume - W[R_V_SOLID * B + j])
    if flags & K.T_ADDED_MASS:
        m_vehicle += m_x
    thrust = 0.0
    if flags & K.T_JET_THRUST:
        thrust_o = rho * q_n * q_n / a_n
        thrust = thrust_o if q_n > 0.0 else 0.0
    drag = 0.0
    if flags & K.T_DRAG:
        drag = 0.5 * rho * W[R_CD * B + j] * math.pi * b * b * u * abs(u)
    amv_force = 0.0
    if flags & K.T_ADDED_MASS_VARIATION:
        amv_force = -dmx_db * w * u
    q_in = q_p - q_n if q_n < 0.0 else q_p
    ram_ref = 0.0
    if flags & K.T_FLUID_MASS:
        ram_ref = rho * q_in * u
    ram = 0.0
    if flags & K.O_COUPLING_CONSISTENT:
        ram = ram_ref
    du = (thrust - drag + amv_force - ram) / m_vehicle

    # ledger rates
    out = q_n > 0.0
    slip = u_n - u  # u_j = q_n / a_n, equal to u_n wherever it is used (out: the valve is open)
    e_jet = 0.5 * rho * q_n * (slip * slip) if out else 0.0
    e_mix_out = 0.5 * rho * q_in * u * u
    e_mix_in = 0.5 * rho * q_in * u * u + q_n * dp_jet_ref
    e_mix = e_mix_out if out else e_mix_in
    spring_rate = math.sqrt(abs(spring) / m_b_total) if m_b_total > 0.0 else 0.0
    return (
        u,
        du,
        w,
        dw,
        dq_p,
        p_cav * q_p,
        e_jet,
        drag * u,
        q_n * dp_visc,
        q_n * dp_valve,
        e_mix,
        -f_kx * w,
        c_jet,
        c_nozzle,
        (reaction - reaction_ref) * w,
        (ram_ref - ram) * u,
        damping_rate,
        spring_rate,
    )


@njit(cache=True, inline='always', error_model='numpy')
def _spheroid(flags, W):
    """e^2 and e of the spheroid at the stage's b (lumped.kernels.added_mass's first lines)."""
    B = BLOCK
    for j in range(B):
        a = W[R_A * B + j]
        ratio = W[R_TB * B + j] / a
        e2 = 1.0 - ratio * ratio
        W[R_E2 * B + j] = e2
        W[R_E * B + j] = math.sqrt(e2)


@njit(cache=True, error_model='numpy', fastmath=False)
def _atanh_pass(W, exact):
    B = BLOCK
    if exact:
        for j in range(B):
            W[R_G * B + j] = math.atanh(W[R_E * B + j])
    else:
        for j in range(B):
            W[R_G * B + j] = _atanh_fast(W[R_E * B + j])


@njit(cache=True, inline='always', error_model='numpy')
def _acc(W, j, c, stage, v):
    """Stage sum of component c: k1, + 2 k2, + 2 k3, + k4 (as lumped.kernels._rk4 sums them)."""
    B = BLOCK
    if stage == 0:
        W[(R_ACC + c) * B + j] = v
    elif stage == 3:
        W[(R_ACC + c) * B + j] = W[(R_ACC + c) * B + j] + v
    else:
        W[(R_ACC + c) * B + j] = W[(R_ACC + c) * B + j] + 2.0 * v


@njit(cache=True, inline='always', error_model='numpy')
def _next(W, j, row, c, stage, half, h, v):
    """Write the next stage's value of component c: y + h/2 k1, y + h/2 k2, y + h k3."""
    B = BLOCK
    if stage < 2:
        W[row * B + j] = W[(R_Y + c) * B + j] + half * v
    elif stage == 2:
        W[row * B + j] = W[(R_Y + c) * B + j] + h * v


@njit(cache=True, inline='always', error_model='numpy')
def _stage(flags, W, stage, h, dt):
    """
    Take RK4 stage `stage` (0..3) of every robot of the block at the stage state.

    Accumulates the stage sum and writes the next stage state.
    """
    B = BLOCK
    half = 0.5 * h
    n_slow = 0
    for j in range(B):
        (
            d0,
            d1,
            d2,
            d3,
            d4,
            d5,
            d6,
            d7,
            d8,
            d9,
            d10,
            d11,
            d12,
            d13,
            d14,
            d15,
            damping_rate,
            spring_rate,
        ) = _rhs(flags, W, j, W[R_TU * B + j], W[R_TB * B + j], W[R_TW * B + j], W[R_TQ * B + j])
        if stage == 0:
            rate = spring_rate if spring_rate > damping_rate else damping_rate  # numba's max()
            slow = rate * dt > 1.5 or W[R_SEAL * B + j] > 0.0
            W[R_SLOW * B + j] = 1.0 if slow else 0.0
            n_slow += 1 if (slow and W[R_ACTIVE * B + j] > 0.0) else 0
        # written out: a loop over c with the 16 values of a tuple is not unrolled by LLVM, and
        # the stage loop then does not vectorise (tried: 4.6e6 robot-steps/s against 1.2e7)
        _acc(W, j, 0, stage, d0)
        _acc(W, j, 1, stage, d1)
        _acc(W, j, 2, stage, d2)
        _acc(W, j, 3, stage, d3)
        _acc(W, j, 4, stage, d4)
        _acc(W, j, 5, stage, d5)
        if not flags & LOSSES_OFF:
            _acc(W, j, 6, stage, d6)
            _acc(W, j, 7, stage, d7)
            _acc(W, j, 8, stage, d8)
            _acc(W, j, 9, stage, d9)
            _acc(W, j, 10, stage, d10)
            _acc(W, j, 11, stage, d11)
            _acc(W, j, 12, stage, d12)
            _acc(W, j, 13, stage, d13)
            _acc(W, j, 14, stage, d14)
            _acc(W, j, 15, stage, d15)
        _next(W, j, R_TU, K.Y_U, stage, half, h, d1)
        _next(W, j, R_TB, K.Y_B, stage, half, h, d2)
        _next(W, j, R_TW, K.Y_W, stage, half, h, d3)
        _next(W, j, R_TQ, K.Y_QP, stage, half, h, d4)
    return n_slow


@njit(cache=True, inline='always', error_model='numpy')
def _valve_after_step(valve, v_cmd, stroke):
    """
    Return the valve's opening after a step (lumped.kernels._advance's stroke and seat).

    It moves by at most `stroke` towards the command; an opening below the seat becomes the seat
    (opening) or 0 (closing: it seals).
    """
    new_valve = v_cmd
    new_valve = valve + stroke if v_cmd > valve + stroke else new_valve
    new_valve = (
        valve - stroke if (v_cmd < valve - stroke and not v_cmd > valve + stroke) else new_valve
    )
    new_valve = new_valve if v_cmd != valve else valve
    below_seat = v_cmd != valve and new_valve > 0.0 and new_valve < K.VALVE_SEAT
    return (K.VALVE_SEAT if v_cmd > valve else 0.0) if below_seat else new_valve


@njit(cache=True, error_model='numpy', fastmath=False)
def _finish(flags, W, h):
    """
    Finish the step: new state y + h/6 (k1 + 2 k2 + 2 k3 + k4), the valve's stroke, the check.

    The check is lumped.kernels._check; commits the robots that pass, flags the ones that fail
    (their state stays the last good one). Returns the number of robots still active.
    """
    B = BLOCK
    h6 = h / 6.0
    n_int = N_LOSSES_OFF if flags & LOSSES_OFF else K.N_INTEGRATED
    n_active = 0
    for j in range(B):
        active = W[R_ACTIVE * B + j] > 0.0 and W[R_SLOW * B + j] == 0.0
        finite = True
        for c in range(n_int):
            y_new = W[(R_Y + c) * B + j] + h6 * W[(R_ACC + c) * B + j]
            W[(R_ACC + c) * B + j] = y_new
            finite = finite and math.isfinite(y_new)
        valve = W[(R_Y + K.Y_VALVE) * B + j]
        new_valve = _valve_after_step(valve, W[R_V * B + j], W[R_STROKE * B + j])
        finite = finite and math.isfinite(new_valve)
        b = W[R_ACC * B + K.Y_B * B + j]
        u = W[R_ACC * B + K.Y_U * B + j]
        code = float(K.OK)
        code = float(K.ERR_SPEED) if abs(u) > W[R_U_MAX * B + j] else code
        code = float(K.ERR_B_HIGH) if b >= W[R_B_MAX * B + j] else code
        code = float(K.ERR_B_LOW) if b <= W[R_B_MIN * B + j] else code
        code = code if finite else float(K.ERR_NONFINITE)
        commit = active and code == float(K.OK)
        for c in range(n_int):
            W[(R_Y + c) * B + j] = W[(R_ACC + c) * B + j] if commit else W[(R_Y + c) * B + j]
        W[(R_Y + K.Y_VALVE) * B + j] = new_valve if commit else valve
        W[R_DONE * B + j] += 1.0 if commit else 0.0
        failed = active and code != float(K.OK)
        W[R_STATUS * B + j] = code if failed else W[R_STATUS * B + j]
        still = W[R_ACTIVE * B + j] > 0.0 and not failed
        W[R_ACTIVE * B + j] = 1.0 if still else 0.0
        n_active += 1 if still else 0
    return n_active


@njit(cache=True, error_model='numpy', fastmath=False)
def _load_block(W, Y, P, q_cmd, valve_cmd, status, start, n, dt):
    B = BLOCK
    for j in range(B):
        real = start + j < n
        i = start + j if real else start  # padding lanes: a copy of the block's first robot
        p = P[i]
        for c in range(K.NY):
            W[(R_Y + c) * B + j] = Y[i, c]
        W[R_Q * B + j] = q_cmd[i]
        W[R_V * B + j] = valve_cmd[i]
        W[R_ACTIVE * B + j] = 1.0 if (real and status[i] == K.OK) else 0.0
        W[R_STATUS * B + j] = float(status[i])
        W[R_DONE * B + j] = 0.0
        W[R_SLOW * B + j] = 0.0
        rho = p[K.P_RHO]
        a = p[K.P_A]
        a_n = p[K.P_A_N]
        W[R_RHO * B + j] = rho
        W[R_A * B + j] = a
        W[R_K * B + j] = p[K.P_K]
        W[R_B0 * B + j] = p[K.P_B0]
        W[R_RELIEF * B + j] = p[K.P_P_RELIEF]
        W[R_STALL * B + j] = p[K.P_P_STALL]
        W[R_TAU * B + j] = p[K.P_PUMP_TAU]
        W[R_A_N * B + j] = a_n
        W[R_C_A * B + j] = 8.0 / 3.0 * math.pi * a
        W[R_K_INLET * B + j] = p[K.P_K_INLET]
        W[R_M_SOLID * B + j] = p[K.P_M_SOLID]
        W[R_V_SOLID * B + j] = p[K.P_V_SOLID]
        W[R_CD * B + j] = p[K.P_CD]
        W[R_C1 * B + j] = p[K.P_C1]
        W[R_VOL_COEF * B + j] = rho * 4.0 / 3.0 * math.pi * a
        W[R_B_MIN * B + j] = p[K.P_B_MIN]
        W[R_B_MAX * B + j] = p[K.P_B_MAX]
        W[R_U_MAX * B + j] = p[K.P_U_MAX]
        W[R_STROKE * B + j] = p[K.P_VALVE_RATE] * dt
    return 0


@njit(cache=True, error_model='numpy', fastmath=False)
def _load_terms(flags, W, P, start, n):
    B = BLOCK
    for j in range(B):
        i = start + j if start + j < n else start
        p = P[i]
        m_shell, inertance = K.shell_inertia(flags, p)
        d_n = p[K.P_D_N]
        W[R_M_SHELL * B + j] = m_shell
        W[R_INERTANCE * B + j] = inertance
        W[R_LAM * B + j] = 32.0 * p[K.P_MU] * p[K.P_L_N] / (d_n * d_n)


@njit(cache=True, error_model='numpy', fastmath=False)
def _stage_state(W):
    """
    Set the first stage's state to the state, and the valve's contraction and sealing flag.

    The valve's contraction over the step, and whether the valve seals a moving flow at the step's
    end (lumped.kernels._advance's valve stroke).
    """
    B = BLOCK
    for j in range(B):
        W[R_TU * B + j] = W[(R_Y + K.Y_U) * B + j]
        W[R_TB * B + j] = W[(R_Y + K.Y_B) * B + j]
        W[R_TW * B + j] = W[(R_Y + K.Y_W) * B + j]
        W[R_TQ * B + j] = W[(R_Y + K.Y_QP) * B + j]
        valve = W[(R_Y + K.Y_VALVE) * B + j]
        W[R_CONTRACTION * B + j] = 1.0 / valve - 1.0
        v_cmd = W[R_V * B + j]
        new_valve = _valve_after_step(valve, v_cmd, W[R_STROKE * B + j])
        seal = v_cmd != valve and new_valve <= 0.0 and 0.0 < valve
        W[R_SEAL * B + j] = 1.0 if seal else 0.0


@njit(cache=True, fastmath=False)
def _slow_steps(flags, W, P, start, n, dt, row):
    """
    Step the robots of the block whose step the vector path does not take.

    Those need sub-steps, or the valve seals a moving flow; lumped.kernels._advance takes that one
    step.
    """
    B = BLOCK
    for j in range(B):
        if start + j >= n or W[R_ACTIVE * B + j] <= 0.0 or W[R_SLOW * B + j] == 0.0:
            continue
        v_cmd = W[R_V * B + j]
        for c in range(K.NY):
            row[c] = W[(R_Y + c) * B + j]
        d, s = K._advance(flags, row, P[start + j], W[R_Q * B + j], v_cmd, 1, dt)
        for c in range(K.NY):
            W[(R_Y + c) * B + j] = row[c]
        W[R_DONE * B + j] += d
        if s != K.OK:
            W[R_STATUS * B + j] = s
            W[R_ACTIVE * B + j] = 0.0


def _advance_batch(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status, exact):
    n = Y.shape[0]
    B = BLOCK
    W = np.zeros(NROWS * B)
    row = np.empty(K.NY)
    h = dt / 1  # lumped.kernels._advance's h = dt / n_sub, n_sub = 1
    spheroid = _exact_added_mass(flags)
    for start in range(0, n, B):
        if n - start < SCALAR_BELOW:
            # a few robots: one at a time (a block would compute BLOCK lanes for them)
            for i in range(start, n):
                if status[i] != K.OK:
                    done[i] = 0
                    continue
                if flags & LOSSES_OFF:  # the single-robot step integrates them: keep the caller's
                    for c in range(N_LOSSES_OFF, K.N_INTEGRATED):
                        row[c] = Y[i, c]
                d, s = K._advance(flags, Y[i], P[i], q_cmd[i], valve_cmd[i], n_steps, dt)
                if flags & LOSSES_OFF:
                    for c in range(N_LOSSES_OFF, K.N_INTEGRATED):
                        Y[i, c] = row[c]
                done[i] = d
                status[i] = s
            break
        _load_block(W, Y, P, q_cmd, valve_cmd, status, start, n, dt)
        _load_terms(flags, W, P, start, n)
        n_active = 0
        for j in range(B):
            n_active += 1 if W[R_ACTIVE * B + j] > 0.0 else 0
        for step in range(n_steps):
            if n_active <= 0:
                break
            _stage_state(W)
            # the stages, each a loop over the block (stage index a constant of each inlined copy)
            if spheroid:
                _spheroid(flags, W)
                _atanh_pass(W, exact)
            n_slow = _stage(flags, W, 0, h, dt)
            if spheroid:
                _spheroid(flags, W)
                _atanh_pass(W, exact)
            _stage(flags, W, 1, h, dt)
            if spheroid:
                _spheroid(flags, W)
                _atanh_pass(W, exact)
            _stage(flags, W, 2, h, dt)
            if spheroid:
                _spheroid(flags, W)
                _atanh_pass(W, exact)
            _stage(flags, W, 3, h, dt)
            # robots needing sub-steps or sealing: the single-robot step (their vector step is
            # discarded)
            if n_slow > 0:
                _slow_steps(flags, W, P, start, n, dt, row)
            n_active = _finish(flags, W, h)
        for j in range(B):
            i = start + j
            if i >= n:
                break
            for c in range(K.NY):
                # LOSSES_OFF: the losses the single-robot steps of _slow_steps added are dropped
                if not (flags & LOSSES_OFF and N_LOSSES_OFF <= c < K.N_INTEGRATED):
                    Y[i, c] = W[(R_Y + c) * B + j]
            done[i] = int(W[R_DONE * B + j])
            status[i] = int(W[R_STATUS * B + j])


def _compiled_copy(func, name: str, **options):
    """
    Return func compiled by numba under its own name, with these options.

    numba's on-disk cache files a function under its qualified name and line, not its compile
    options: two options of one Python function would share (and overwrite) one cache entry, so
    each copy gets a name of its own.
    """
    copy = types_module.FunctionType(
        func.__code__, func.__globals__, name, func.__defaults__, func.__closure__
    )
    copy.__qualname__ = name
    copy.__doc__ = func.__doc__
    return njit(cache=True, error_model='numpy', **options)(copy)


# advance_batch_exact and advance_batch_fast: one Python body, compiled with and without FAST_MATH
_advance_batch_exact = _compiled_copy(_advance_batch, '_advance_batch_exact')
_advance_batch_fast = _compiled_copy(_advance_batch, '_advance_batch_fast', fastmath=FAST_MATH)


@njit(cache=True, fastmath=False)
def advance_batch_exact(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status):
    """
    Advance every robot i with status[i] == OK by n_steps fixed steps of dt, exactly.

    Each robot holds (q_cmd[i], valve_cmd[i]); done[i]: steps it made, status[i]:
    lumped.kernels.OK or ERR_*. The single-robot arithmetic and libm's atanh: bit for bit the
    single-robot runs.
    """
    _advance_batch_exact(literally(flags), Y, P, q_cmd, valve_cmd, n_steps, dt, done, status, True)


@njit(cache=True, fastmath=False)
def advance_batch_fast(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status):
    """advance_batch_exact with the vectorised atanh and FAST_MATH (the default)."""
    _advance_batch_fast(literally(flags), Y, P, q_cmd, valve_cmd, n_steps, dt, done, status, False)


def batch_kernel(flags: int, exact: bool = False, n_state: int = K.NY):
    """
    Return the compiled entry point of advance_batch_exact or advance_batch_fast for this term set.

    Compiles or loads only that path, once. Called as
    kernel(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status).
    """
    if flags & K.O_NOZZLE_FOLLOWS_SHELL:
        raise ValueError(
            "options.nozzle_section: 'shell' is not in the batch kernel; allowed here: 'rigid' "
            '(run such a scene one robot at a time, LumpedModel.advance)'
        )
    if flags & K.O_HYPERELASTIC:
        raise ValueError(
            "material.law: a rubber membrane is not in the batch kernel; allowed here: 'linear' "
            '(run such a scene one robot at a time, LumpedModel.advance)'
        )
    return K.specialised(
        advance_batch_exact if exact else advance_batch_fast,
        flags,
        np.zeros((1, n_state)),
        np.zeros((1, K.NP)),
        np.zeros(1),
        np.zeros(1),
        0,
        1e-4,
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
    )


# numba keys this file's cache on this file alone: drop it when a module compiled in changes
drop_stale_cache(advance_batch_exact, (K, model_io))
