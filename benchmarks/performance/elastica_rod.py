"""
PyElastica 1.0 reference point for bench_shell.py (runs inside benchmarks/.venv/pyelastica only).

A straight, rubber-like Cosserat rod (E = 1 MPa, L = 0.2 m, r = 5 mm, rho = 1100 kg/m^3, Poisson
0.5) clamped at one end, a small transverse tip force ramped up over 0.1 s, uniform analytical
damping, explicit PositionVerlet at a fixed step.  After an untimed warm-up (numba compilation)
the timed part steps the collection with ``stepper.step`` in a plain loop (no tqdm), so the wall
time is PyElastica's own stepping cost.  The last line printed is one JSON object.

The static tip deflection is compared with Euler-Bernoulli F L^3 / (3 E I) as a sanity check that
the rod is set up right and stable (the force keeps the deflection at ~5 % of the length).

    python elastica_rod.py --elements 50 --dt 4e-5 --duration 3.0
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

os.environ.setdefault('NUMBA_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import elastica as ea  # noqa: E402
import numpy as np  # noqa: E402

LENGTH_M = 0.2
RADIUS_M = 5e-3
DENSITY = 1100.0
YOUNGS_PA = 1.0e6
TIP_FORCE_N = 2.0e-3  # Euler-Bernoulli deflection ~ 10 mm
DAMPING_PER_S = 10.0  # uniform velocity damping rate (the first bending mode is ~ 6.6 rad/s)
RAMP_S = 0.1


class RodSimulator(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping):
    pass


def build(n_elements: int, dt: float):
    sim = RodSimulator()
    rod = ea.CosseratRod.straight_rod(
        n_elements,
        start=np.zeros(3),
        direction=np.array([1.0, 0.0, 0.0]),
        normal=np.array([0.0, 1.0, 0.0]),
        base_length=LENGTH_M,
        base_radius=RADIUS_M,
        density=DENSITY,
        youngs_modulus=YOUNGS_PA,
        shear_modulus=YOUNGS_PA / (2 * 1.5),
    )
    sim.append(rod)
    sim.constrain(rod).using(
        ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,)
    )
    sim.add_forcing_to(rod).using(
        ea.EndpointForces,
        start_force=np.zeros(3),
        end_force=np.array([0.0, -TIP_FORCE_N, 0.0]),
        ramp_up_time=RAMP_S,
    )
    sim.dampen(rod).using(
        ea.AnalyticalLinearDamper, uniform_damping_constant=DAMPING_PER_S, time_step=dt
    )
    sim.finalize()
    return sim, rod


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument('--elements', type=int, default=50)
    ap.add_argument('--dt', type=float, default=4e-5)
    ap.add_argument('--duration', type=float, default=3.0, help='simulated seconds timed')
    ap.add_argument('--warmup-steps', type=int, default=200)
    args = ap.parse_args()

    stepper = ea.PositionVerlet()
    # warm-up on a throw-away system: numba compiles every kernel once
    warm, _ = build(args.elements, args.dt)
    t = np.float64(0.0)
    for _ in range(args.warmup_steps):
        t = stepper.step(warm, t, np.float64(args.dt))

    sim, rod = build(args.elements, args.dt)
    n_steps = int(round(args.duration / args.dt))
    dt = np.float64(args.dt)
    t = np.float64(0.0)
    start = time.perf_counter()
    for _ in range(n_steps):
        t = stepper.step(sim, t, dt)
    wall = time.perf_counter() - start

    pos = rod.position_collection
    finite = bool(np.all(np.isfinite(pos)))
    tip_deflection = float(-pos[1, -1]) if finite else float('nan')
    inertia = math.pi * RADIUS_M**4 / 4
    eb = TIP_FORCE_N * LENGTH_M**3 / (3 * YOUNGS_PA * inertia)
    out = {
        'pyelastica_version': getattr(ea, '__version__', None) or _version(),
        'python': platform.python_version(),
        'elements': args.elements,
        'dt_s': args.dt,
        'steps': n_steps,
        'simulated_s': float(t),
        'wall_s': wall,
        'wall_per_sim_s': wall / float(t),
        'real_time_factor': float(t) / wall,
        'us_per_step': wall / n_steps * 1e6,
        'ns_per_element_step': wall / (n_steps * args.elements) * 1e9,
        'finite': finite,
        'tip_deflection_m': tip_deflection,
        'euler_bernoulli_deflection_m': eb,
    }
    print(json.dumps(out))
    return 0 if finite else 1


def _version() -> str | None:
    try:
        from importlib.metadata import version

        return version('pyelastica')
    except Exception:
        return None


if __name__ == '__main__':
    sys.exit(main())
