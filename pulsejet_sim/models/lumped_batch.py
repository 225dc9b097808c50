"""numba kernels that advance N lumped robots in one call (the vector environment's engine).

The physics is not repeated here: every robot is advanced by ``lumped_kernels._advance``, the very
function (same right-hand side, same RK4 with stability sub-steps, same valve and sealing logic,
same bound checks) that ``LumpedModel.advance`` runs for one robot, specialised on the same literal
term flags. A batch of N identical robots therefore equals N single-robot runs bit for bit (tested).

Layout: states ``Y`` (N, NY) and parameters ``P`` (N, NP), C-contiguous, one row per robot (one
scene's parameters tiled, or per-robot values); commands ``q_cmd`` and ``valve_cmd`` (N,). A robot
whose step fails keeps its last good state, gets a non-zero ``status`` (lumped_kernels.ERR_*) and is
skipped by later calls until the caller resets it (``status[i] = OK``).
"""
from __future__ import annotations

import numpy as np
from numba import literally, njit

from pulsejet_sim.models import lumped_kernels as K


@njit(cache=True)
def _advance_batch(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status):
    n = Y.shape[0]
    for i in range(n):
        if status[i] != K.OK:
            done[i] = 0
            continue
        d, s = K._advance(flags, Y[i], P[i], q_cmd[i], valve_cmd[i], n_steps, dt)
        done[i] = d
        status[i] = s


@njit(cache=True)
def advance_batch(flags, Y, P, q_cmd, valve_cmd, n_steps, dt, done, status):
    """Advance every robot i with status[i] == OK by n_steps fixed steps of dt holding
    (q_cmd[i], valve_cmd[i]); done[i]: steps it made, status[i]: lumped_kernels.OK or ERR_*."""
    _advance_batch(literally(flags), Y, P, q_cmd, valve_cmd, n_steps, dt, done, status)


def batch_kernel(flags: int, n_state: int = K.NY):
    """The compiled entry point of advance_batch for this term set (compiles or loads it once)."""
    Y = np.zeros((1, n_state))
    P = np.zeros((1, K.NP))
    return K.specialised(advance_batch, flags, Y, P, np.zeros(1), np.zeros(1), 0, 1e-4,
                         np.zeros(1, np.int64), np.zeros(1, np.int64))
