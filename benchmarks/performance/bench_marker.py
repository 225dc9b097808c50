"""
Cost of sim_node's mantle Marker: Python objects serialised, or serialised from arrays.

The shell robot's meridian (the default scene's mesh), revolved in MANTLE_MARKER_SEGMENTS facets:
what sim_node sends five times a second while a viewer is subscribed. Both ways run interleaved in
one process, `--repeats` times each; the table gives medians and p90 of the wall time per
message (the interpreter is held all that time) and their ratio.

    .venv/bin/python -m benchmarks.performance.bench_marker [--repeats 200]

Writes benchmarks/results/marker.md.
"""

from __future__ import annotations

import argparse
import time

from benchmarks.common import header, write
import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--repeats', type=int, default=200)
    args = parser.parse_args()
    from pulsejet_sim.engine.simulation import Simulation
    from pulsejet_sim.ros import messages
    from pulsejet_sim.scene import load_scene
    from rclpy.serialization import serialize_message

    sim = Simulation(load_scene('shell_robot', command_driven=True).model)
    r_m, z_m = sim.profile()
    n_points = len(messages.mantle_vertices(r_m, z_m))

    def objects():
        return serialize_message(messages.mantle_marker(r_m, z_m, 1.0, 'base_link'))

    def arrays():
        return messages.mantle_marker_cdr(r_m, z_m, 1.0, 'base_link')

    assert len(objects()) == len(arrays())
    times = {'objects': [], 'arrays': []}
    for _ in range(args.repeats):
        for name, build in (('objects', objects), ('arrays', arrays)):
            t0 = time.perf_counter()
            build()
            times[name].append(time.perf_counter() - t0)
    rows = []
    for name, what in (
        ('objects', 'mantle_marker + serialize_message (one Point per vertex)'),
        ('arrays', 'mantle_marker_cdr (points from a float64 array)'),
    ):
        t = np.array(times[name]) * 1e3
        rows.append(f'| {what} | {np.median(t):.3f} | {np.percentile(t, 90):.3f} |')
    ratio = np.median(times['objects']) / np.median(times['arrays'])
    text = header(
        'Mantle Marker: Python objects against arrays',
        f'python -m benchmarks.performance.bench_marker --repeats {args.repeats}',
    ) + (
        f'shell_robot meridian: {len(r_m)} nodes, {n_points} vertices '
        f'({messages.MANTLE_MARKER_SEGMENTS} facets); {args.repeats} interleaved repeats '
        'each.\n\n'
        '| build and serialise one Marker | median ms | p90 ms |\n|---|---|---|\n'
        + '\n'.join(rows)
        + f'\n\nmedian ratio objects / arrays: {ratio:.1f}\n\n'
        'Not measured here: the send-time jitter of sim_node with the Marker subscribed against '
        'an idle process (issue 26, point 5); this table is the cost the array path removes from '
        'the pacing thread.\n'
    )
    write('marker', text)


if __name__ == '__main__':
    main()
