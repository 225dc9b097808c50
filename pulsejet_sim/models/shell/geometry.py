"""
Reference meridian profiles of the axisymmetric mantle (paper 000), sampled at N+1 nodes.

Conventions (shared with shell/kernels.py)
-----------------------------------------
* Body axis ``z`` points forward (the swimming direction).  The meridian runs from the **pole**
  (node 0, on the axis ``r = 0``, the front tip of the mantle) to the **ring** (node N), where the
  mantle is clamped to the rigid cap that carries the nozzle; the ring sits at ``z = 0`` and the
  jet leaves backwards (towards ``-z``).
* ``X`` is the reference arc length, the nodes are equally spaced in ``X``.
* ``theta0`` is the angle of the tangent ``e_a = (cos theta, sin theta)`` in the ``(r, z)`` plane.
  Going from the front pole backwards the tangent turns downwards, so ``theta0`` is 0 at a smooth
  pole and negative along the mantle (about ``-pi/2`` along a cylinder).

Every geometry is first drawn as a dense polyline (about 4000 points), then resampled at equal arc
length; the nodal tangent angle comes from the dense polyline.  Kinks (cap/cylinder junction,
cone apex) are therefore allowed: the kernels take the discrete reference configuration as the
stress-free state, whatever its curvature.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

import numpy as np
from pulsejet_sim.core.model_io import ModelError
from pulsejet_sim.models.shell.scene_keys import GEOMETRY_KINDS, GEOMETRY_SPECS, read

_DENSE = 4001


@dataclass(frozen=True)
class ReferenceMeridian:
    """Reference meridian at the nodes (arrays of length N+1)."""

    X: np.ndarray  # reference arc length from the pole, m
    r0: np.ndarray  # reference radius, m (r0[0] == 0)
    z0: np.ndarray  # reference axial position, m (z0[-1] == 0, the ring)
    theta0: np.ndarray  # tangent angle, rad

    @property
    def length_m(self) -> float:
        return float(self.X[-1])

    @property
    def ring_radius_m(self) -> float:
        return float(self.r0[-1])

    def volume_m3(self) -> float:
        return float(self._frusta().sum())

    def _frusta(self) -> np.ndarray:
        r, z = self.r0, self.z0
        return math.pi / 3.0 * (r[:-1] ** 2 + r[:-1] * r[1:] + r[1:] ** 2) * (z[:-1] - z[1:])

    def internal_inertance_per_m(self) -> float:
        """
        Inertance Lambda, 1/m, of the water inside for a uniform dilation of the cavity.

        One-dimensional internal flow (paper 001 section 3.4, eqs. 4-6, carried over to any
        profile): the water crossing the section at z is the volume behind it, so its flux is
        ``Q V_b(z)/V`` for an outflow ``Q`` at the open end, and its kinetic energy
        ``1/2 rho Q^2 Lambda`` with ``Lambda = int (V_b(z)/V)^2 / (pi r(z)^2) dz`` from the pole
        to the open end.  For paper 001's ellipsoid this is its ``m_b`` over ``(dV/db)^2``.
        """
        flux, dz = self._internal_flux('internal_inertia: one_dimensional')
        area = math.pi * self.r0**2
        f = np.zeros_like(self.r0)
        f[1:] = flux[1:] ** 2 / area[1:]
        return float(np.sum(0.5 * (f[:-1] + f[1:]) * dz))

    def internal_momentum_length_m(self) -> float:
        """
        Length S, m, of the same flow's momentum: the water inside carries ``rho S V'`` along +z.

        ``S = int (V_b(z)/V) dz`` from the open end to the pole: the flux ``V' V_b(z)/V`` through
        each section, integrated over the axis, is the water's volume times its mean axial
        velocity relative to the body (docs/theory/shell.md).
        """
        flux, dz = self._internal_flux('internal_flow_momentum: true')
        return float(np.sum(0.5 * (flux[:-1] + flux[1:]) * dz))

    def _internal_flux(self, option: str) -> tuple[np.ndarray, np.ndarray]:
        """Share V_b/V of the volume behind each node, and the nodes' axial steps dz, m."""
        dz = self.z0[:-1] - self.z0[1:]
        if np.any(dz < 0.0):
            raise ModelError(
                f'fluid.{option} needs a mantle whose axial position falls monotonically from '
                'the pole to the open end (a one-dimensional flow along the axis); this profile '
                'turns back; allowed: internal_inertia: none'
            )
        behind = np.concatenate([[0.0], np.cumsum(self._frusta())])
        return behind / behind[-1], dz


def _num(section: Mapping[str, Any], kind: str, key: str, default=None) -> float:
    """Return a geometry number by its declaration (scene_keys.GEOMETRY_SPECS), or ModelError."""
    return read(section, 'geometry', key, GEOMETRY_SPECS[kind], default=default)


def _ellipsoid(g):
    """
    Prolate/oblate ellipsoid of revolution, truncated at the back where r = opening radius.

    ``r = b sin(phi)``, ``z = a cos(phi)`` with ``phi = 0`` at the front pole; the ring is on the
    rear half (``phi > pi/2``) where ``b sin(phi) = opening_radius_m``.
    """
    a = _num(g, 'ellipsoid', 'semi_axis_axial_m')
    b = _num(g, 'ellipsoid', 'semi_axis_radial_m')
    ro = _num(g, 'ellipsoid', 'opening_radius_m')
    if ro >= b:
        raise ModelError(
            f'geometry.opening_radius_m: {ro!r} m is not below semi_axis_radial_m={b} m; '
            f'allowed: 0 < opening_radius_m < semi_axis_radial_m'
        )
    phi_e = math.pi - math.asin(ro / b)
    phi = np.linspace(0.0, phi_e, _DENSE)
    return b * np.sin(phi), a * np.cos(phi)


def _cone(g):
    """
    Cone from a rounded apex (front pole) widening to the ring at the back.

    The apex is rounded by a spherical cap of radius ``tip_radius_m`` tangent to the cone (so the
    pole director is radial, theta = 0); ``tip_radius_m = 0`` keeps a sharp apex.
    """
    L = _num(g, 'cone', 'length_m')
    R = _num(g, 'cone', 'base_radius_m')
    rt = _num(g, 'cone', 'tip_radius_m', default=0.2 * R)
    beta = math.atan2(R, L)  # half-opening angle
    # tangent point of the tip sphere: the sphere centre on the axis at distance d from the apex
    # with d sin(beta) = rt; the cap spans polar angle 0 .. pi/2 - beta
    psi = math.pi / 2 - beta
    d = rt / math.sin(beta) if rt > 0 else 0.0
    if d >= L * 0.9:
        raise ModelError(
            f'geometry.tip_radius_m: {rt!r} m rounds off most of the cone; '
            f'allowed: tip_radius_m < {0.9 * L * math.sin(beta):.4g} m'
        )
    pts_r, pts_z = [], []
    if rt > 0:
        t = np.linspace(0.0, psi, _DENSE // 4)
        zc = L - d  # sphere centre (apex at z = L)
        pts_r.append(rt * np.sin(t))
        pts_z.append(zc + rt * np.cos(t))
        r_start, z_start = rt * math.sin(psi), zc + rt * math.cos(psi)
    else:
        r_start, z_start = 0.0, L
    s = np.linspace(0.0, 1.0, _DENSE)[1:] if rt > 0 else np.linspace(0.0, 1.0, _DENSE)
    pts_r.append(r_start + (R - r_start) * s)
    pts_z.append(z_start + (0.0 - z_start) * s)
    return np.concatenate(pts_r), np.concatenate(pts_z)


def _cap_cylinder(g):
    """
    Return the authors' robot mantle: a spherical cap at the front, then a cylinder.

    The cap is opened to ``cap_opening_rad``, then a cylinder of radius ``cap_radius_m *
    sin(cap_opening_rad)`` runs back to the ring.

    Reading of "cap radius 31 mm opened at pi/4, continued by a cylinder": the cap spans polar
    angles 0..pi/4 of a 31 mm sphere (so the cylinder radius is 21.9 mm, with a kink of pi/4 at
    the junction); ``cylinder_length_m`` sets the mantle length.
    """
    Rc = _num(g, 'cap_cylinder', 'cap_radius_m')
    al = _num(g, 'cap_cylinder', 'cap_opening_rad')
    Lc = _num(g, 'cap_cylinder', 'cylinder_length_m')
    n_cap = max(50, int(_DENSE * Rc * al / (Rc * al + Lc + 1e-12)))
    t = np.linspace(0.0, al, n_cap)
    h_cap = Rc * (1 - math.cos(al))
    r_cap = Rc * np.sin(t)
    z_cap = Lc + h_cap - Rc * (1 - np.cos(t))
    Rcyl = Rc * math.sin(al)
    s = np.linspace(0.0, 1.0, max(50, _DENSE - n_cap))[1:]
    return np.concatenate([r_cap, np.full(s.size, Rcyl)]), np.concatenate([z_cap, Lc * (1 - s)])


def _points(g):
    """
    Arbitrary profile: ``points: [[r, z], ...]`` from the pole (r = 0) to the ring.

    The polyline is refined linearly; z is shifted so that the ring sits at z = 0.
    """
    pts = g.get('points')
    try:
        arr = np.asarray(pts, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(
            f'geometry.points: {pts!r} is not a list of [r, z] pairs; allowed: >= 3 pairs of '
            'numbers'
        ) from None
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 3 or not np.all(np.isfinite(arr)):
        raise ModelError(
            f'geometry.points: shape {arr.shape} rejected; allowed: >= 3 finite [r, z] pairs'
        )
    if abs(arr[0, 0]) > 1e-12:
        raise ModelError(
            f'geometry.points: first point r={arr[0, 0]!r} is not on the axis; allowed: first '
            'point '
            f'r = 0 (the pole)'
        )
    if np.any(arr[1:, 0] <= 0):
        raise ModelError(
            'geometry.points: a point after the pole has r <= 0; allowed: r > 0 after the first '
            'point'
        )
    seg = np.hypot(np.diff(arr[:, 0]), np.diff(arr[:, 1]))
    if np.any(seg <= 0):
        raise ModelError('geometry.points: repeated point; allowed: distinct consecutive points')
    s = np.concatenate([[0.0], np.cumsum(seg)])
    sd = np.linspace(0.0, s[-1], _DENSE)
    return np.interp(sd, s, arr[:, 0]), np.interp(sd, s, arr[:, 1])


_BUILDERS = {
    'ellipsoid': _ellipsoid,
    'cone': _cone,
    'cap_cylinder': _cap_cylinder,
    'points': _points,
}


def build_reference_meridian(geometry: Mapping[str, Any], n_elements: int) -> ReferenceMeridian:
    """Sample the geometry of a scene at ``n_elements + 1`` nodes equally spaced in arc length."""
    if not isinstance(geometry, Mapping):
        raise ModelError(
            f'geometry: {geometry!r} is not a mapping; allowed: a mapping with kind: one of '
            f'{", ".join(GEOMETRY_KINDS)}'
        )
    kind = geometry.get('kind')
    if kind not in _BUILDERS:
        raise ModelError(
            f'geometry.kind: {kind!r} is not known; allowed: one of {", ".join(GEOMETRY_KINDS)}'
        )
    r, z = _BUILDERS[kind](geometry)
    z = z - z[-1]
    seg = np.hypot(np.diff(r), np.diff(z))
    keep = np.concatenate([[True], seg > 1e-14])
    r, z = r[keep], z[keep]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(r), np.diff(z)))])
    # tangent angle on the dense polyline, per segment, unwrapped, at segment midpoints. The C
    # library's atan2, not np.arctan2: numpy runs arctan2 on CPUs with AVX-512 through kernels
    # whose last bits differ from the C library's (and from its own on other CPUs), so the same
    # scene would start from a reference angle an ulp apart on two machines and a stored study
    # would not rerun bit for bit (seen on 2026-12-02: test/test_paper000_study.py)
    ang = np.unwrap(
        np.fromiter(map(math.atan2, np.diff(z), np.diff(r)), dtype=float, count=len(r) - 1)
    )
    smid = 0.5 * (s[:-1] + s[1:])
    X = np.linspace(0.0, s[-1], n_elements + 1)
    rn = np.interp(X, s, r)
    zn = np.interp(X, s, z)
    # tangent angle at the arc-length positions of the nodes; at the two ends the segment-midpoint
    # values are extrapolated linearly (2nd order), so a smooth pole gets theta0 = 0 to O(ds^2)
    sm = np.concatenate([[0.0], smid, [s[-1]]])
    am = np.concatenate(
        [[ang[0] - 0.5 * (ang[1] - ang[0])], ang, [ang[-1] + 0.5 * (ang[-1] - ang[-2])]]
    )
    th = np.interp(X, sm, am)
    rn[0] = 0.0
    zn[-1] = 0.0
    if np.any(rn[1:] <= 0):
        raise ModelError(
            f'geometry: the {kind} profile touches the axis away from the pole; allowed: r > 0 '
            f'after the pole'
        )
    return ReferenceMeridian(X=X, r0=rn, z0=zn, theta0=th)
