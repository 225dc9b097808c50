"""
The periodic pull of the cable routine: one definition for the shell's kernels and the controller.

``activation(t, ...)`` is the routine both the shell model's built-in routine
(``shell.kernels.routine``, inside the numba kernels) and ``pulsejet_sim.routines.CableRoutine``
(controller_node and the offline runner, as commands) evaluate, so a command-driven run pulls with
the same bits as the model's own routine at the same times. A rise over the contraction time, a
fall over the release time, rest for the remaining period: half cosines, or straight lines (the
authors' code's ``triangularPulse``, paper 000's study).

numba's cache of a kernel that calls this function is keyed on the kernel's own file; the shell
kernels therefore drop their cache when this file changes (core.kernel_cache).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True)
def activation(t, start_delay_s, frequency_hz, contraction_s, release_s, triangle):
    """
    Return the activation a(t) in [0, 1] and da/dt, 1/s, of the periodic pull at time t, s.

    Rest before ``start_delay_s``; then, every period ``1/frequency_hz``, a rise over
    ``contraction_s``, a fall over ``release_s`` and rest (half cosines; straight lines when
    ``triangle``).
    """
    t = t - start_delay_s
    if t < 0.0:
        return 0.0, 0.0
    per = 1.0 / frequency_hz
    ph = t - per * math.floor(t / per)
    tc = contraction_s
    tr = release_s
    if ph < tc:
        if triangle:
            return ph / tc, 1.0 / tc
        x = math.pi * ph / tc
        return 0.5 * (1.0 - math.cos(x)), 0.5 * math.pi / tc * math.sin(x)
    if ph < tc + tr:
        if triangle:
            return 1.0 - (ph - tc) / tr, -1.0 / tr
        x = math.pi * (ph - tc) / tr
        return 0.5 * (1.0 + math.cos(x)), -0.5 * math.pi / tr * math.sin(x)
    return 0.0, 0.0
