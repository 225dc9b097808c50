"""
The mantle surface as triangles, from the meridian (numpy only; no ROS, no viewer library).

One mesh for every view: sim_node's Marker (pulsejet_sim.ros.messages) and the Foxglove scene of
`pulsejet view` (pulsejet_sim.view.foxglove_live) list the same vertices.
"""

from __future__ import annotations

import numpy as np
from pulsejet_sim.core.topics import MANTLE_MARKER_SEGMENTS


def mantle_vertices(r_m, z_m, segments: int = MANTLE_MARKER_SEGMENTS) -> np.ndarray:
    """
    Return the mantle surface's triangle vertices, (6 * segments * elements, 3) float64, m.

    The meridian (node radii r_m, axial positions z_m) revolved about the body's x axis in
    `segments` facets, two triangles per element and facet, in the order mantle_marker lists
    them: (lower k, upper k, upper k+1), (lower k, upper k+1, lower k+1).
    """
    r = np.asarray(r_m, dtype=np.float64)
    z = np.asarray(z_m, dtype=np.float64)
    angles = 2.0 * np.pi * np.arange(segments + 1) / segments
    ring = np.empty((len(r), segments + 1, 3))
    ring[:, :, 0] = z[:, None]
    ring[:, :, 1] = r[:, None] * np.cos(angles)
    ring[:, :, 2] = r[:, None] * np.sin(angles)
    lower, upper = ring[:-1], ring[1:]
    k, k1 = slice(0, segments), slice(1, segments + 1)
    corners = (lower[:, k], upper[:, k], upper[:, k1], lower[:, k], upper[:, k1], lower[:, k1])
    return np.stack(corners, axis=2).reshape(-1, 3)
