"""
Numerical experiment (not the study): why the muscle-driven cone converges at first order.

The muscle's desired radius is the rest profile moved inwards by `amplitude x a(t) x max(r0) x
s(X)` (docs/theory/shell.md). Until issue 23's fix `models.shell.model.muscle_shape` took max(r0)
over the elements' midpoints. On the cone the largest radius is at the ring, where r0 grows
linearly, so that maximum falls short of the ring's radius by half an element's rise: an O(ds)
error in every element's depth, hence first order in the mesh. On the ellipsoid the largest radius
is where the wall is parallel to the axis, and the midpoints' maximum is off by O(ds^2).

The experiment reruns the four muscle-driven corner cases of paper000_resolution at 32, 64, 128 and
256 elements (0.25 ms) with three maxima, each passed to `muscle_shape` explicitly: the midpoints'
(the code before the fix, "midpoints"), the ring's (the last midpoint's radius extrapolated half an
element, exact for the cone's straight wall, kept if larger than the midpoints': "ring
extrapolated"; the first run's "ring max") and the reference meridian's own, max(r0) over its nodes
(the model since the fix, "meridian"). No value of the study changes. Writes
benchmarks/results/paper000_study/muscle_depth.md.

    .venv/bin/python -m benchmarks.validation.paper000_muscle_depth
"""

from __future__ import annotations

import math
import sys
import time

from benchmarks import common
from benchmarks.validation.paper000_resolution import at_resolution, CASES, OUT
from pulsejet_sim.models.shell import model as shell_model
from pulsejet_sim.studies.sweep import load_sweep, run_one

ELEMENTS = (32, 64, 128, 256)
DT_S = 2.5e-4
MODEL_SHAPE = shell_model.muscle_shape


def muscle_shape_midpoints_max(desired, Xm, r0m, taper, amp, rmax_m):
    """muscle_shape with max(r0) over the element midpoints (the code before issue 23's fix)."""
    return MODEL_SHAPE(desired, Xm, r0m, taper, amp, float(r0m.max()))


def muscle_shape_ring_extrapolated(desired, Xm, r0m, taper, amp, rmax_m):
    """muscle_shape with max(r0) including the ring's radius extrapolated from two midpoints."""
    if desired != 'constant_depth':
        raise ValueError(f'desired_radius {desired!r}: this experiment covers constant_depth')
    ring = r0m[-1] + 0.5 * (r0m[-1] - r0m[-2])  # the last midpoint extrapolated to the ring
    return MODEL_SHAPE(desired, Xm, r0m, taper, amp, max(float(r0m.max()), float(ring)))


VARIANTS = (
    ('midpoints', muscle_shape_midpoints_max),
    ('ring extrapolated', muscle_shape_ring_extrapolated),
    ('meridian', MODEL_SHAPE),
)


def orders(values):
    return [
        math.log2(abs(values[i] - values[i + 1]) / abs(values[i + 1] - values[i + 2]))
        for i in range(len(values) - 2)
    ]


def main() -> int:
    _, runs = load_sweep('paper000_study')
    lines = [
        common.header(
            "Paper 000 study: the muscle depth's maximum radius and the mesh order",
            'python -m benchmarks.validation.paper000_muscle_depth',
        ).rstrip('\n'),
        '',
        'Peak vehicle speed (m/s) of the muscle-driven corner cases of `paper000_resolution` over '
        f'{", ".join(map(str, ELEMENTS))} elements at {DT_S * 1e3:g} ms; observed orders of '
        'consecutive triples. max(r0) passed to the muscle\'s depth: "midpoints", over element '
        'midpoints (the code before issue 23\'s fix; the first run\'s "as coded"); "ring '
        'extrapolated", the larger of that and the last midpoint extrapolated half an element to '
        "the ring (the cone's largest radius; the first run's \"ring max\"); \"meridian\", over "
        "the reference meridian's nodes (the model since the fix). A numerical experiment, not "
        'the study.',
        '',
        '| case | max(r0) | ' + ' | '.join(f'{n} el' for n in ELEMENTS)
        + ' | spread 32-256 | observed orders |',
        '|---|---|' + '---|' * len(ELEMENTS) + '---|---|',
    ]
    start = time.perf_counter()
    for study, labels in CASES:
        if study != 'internal':
            continue
        spec = next(r for r in runs if r.study == study and dict(r.labels) == labels)
        for name, shape in VARIANTS:
            shell_model.muscle_shape = shape
            try:
                peaks = []
                for n in ELEMENTS:
                    row = run_one(at_resolution(spec, n, DT_S))
                    peaks.append(
                        row.metrics['peak_speed_m_s']
                        if row.metrics and not row.fault else float('nan')
                    )
            finally:
                shell_model.muscle_shape = MODEL_SHAPE
            spread = abs(peaks[0] / peaks[-1] - 1) * 100
            lines.append(
                f'| {spec.name} | {name} | ' + ' | '.join(f'{p:.7f}' for p in peaks)
                + f' | {spread:.3f} % | ' + ', '.join(f'{o:.2f}' for o in orders(peaks)) + ' |'
            )
            print(lines[-1], flush=True)
    lines += ['', f'Wall time {time.perf_counter() - start:.0f} s.', '']
    (OUT / 'muscle_depth.md').write_text('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
