r"""Boot-seal (bellows) mesh generator for the virtual boot seal of seed 000 §5.3.

The seal is a corrugated rubber sleeve around the z axis: a meridian profile :math:`(R(t), Z(t))` swept about
the axis, with a wall of constant thickness along the profile normal. From bottom to top: a cylindrical
cuff of radius `r_bottom` and height `cuff`, `n_convolutions` convolutions on a cone from `r_bottom` to
`r_top`,

.. math::

    R(z) = r_b + (r_t - r_b)\, \xi^2 (3 - 2 \xi) + \frac{a}{2} (1 - \cos(2 \pi n \xi)), \qquad
    \xi = \frac{z - \mathrm{cuff}}{H - 2\,\mathrm{cuff}},

and a cylindrical top cuff of radius `r_top`. The wall occupies
:math:`(R(t) + \eta\, t_w n_R,\ Z(t) + \eta\, t_w n_Z)`, :math:`\eta \in [-1/2, 1/2]`, with
:math:`(n_R, n_Z)` the unit normal of the mid-profile. The structured grid (:math:`\eta`: n_thick,
:math:`\phi`: n_phi, profile arc length: n_profile) is split into 6 Kuhn tetrahedra per cell, periodic in
:math:`\phi` (conforming across the seam). Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physar.errors import MeshError
from physar.geometry.mesh import _KUHN, TetMesh, tet_signed_volumes


@dataclass(frozen=True)
class SealGeometry:
    """Dimensions of the bellows [m] (defaults: a gear-lever boot, 90 mm high, 3 convolutions)."""

    r_bottom: float = 0.060
    r_top: float = 0.025
    height: float = 0.090
    cuff: float = 0.010
    n_convolutions: int = 3
    amplitude: float = 0.008
    thickness: float = 0.003

    def check(self) -> None:
        if min(self.r_bottom, self.r_top, self.height, self.thickness) <= 0:
            raise MeshError(f"seal: radii, height and thickness must be positive, got {self}")
        if not 0 < 2 * self.cuff < self.height:
            raise MeshError(f"seal: cuff {self.cuff} m must be in (0, height/2 = {self.height / 2})")
        if self.n_convolutions < 0 or self.amplitude < 0:
            raise MeshError("seal: n_convolutions and amplitude must be >= 0")
        if self.thickness / 2 >= min(self.r_top, self.r_bottom):
            raise MeshError("seal: the wall is thicker than the radius")
        kappa = self.max_curvature()
        if kappa * self.thickness / 2 >= 0.9:
            raise MeshError(
                f"seal: the convolutions are too sharp for a wall of {self.thickness} m (profile curvature "
                f"radius {1 / kappa:.4g} m < thickness / 2); reduce amplitude or n_convolutions")

    def profile(self, z: np.ndarray) -> np.ndarray:
        """Mid-wall radius R(z) [m]."""
        z = np.asarray(z, dtype=float)
        zc0, zc1 = self.cuff, self.height - self.cuff
        xi = np.clip((z - zc0) / (zc1 - zc0), 0.0, 1.0)
        rlin = self.r_bottom + (self.r_top - self.r_bottom) * xi * xi * (3 - 2 * xi)  # C1 at the cuffs
        return rlin + 0.5 * self.amplitude * (1 - np.cos(2 * np.pi * self.n_convolutions * xi))

    def max_curvature(self) -> float:
        z = np.linspace(0, self.height, 4001)
        R = self.profile(z)
        d1 = np.gradient(R, z)
        d2 = np.gradient(d1, z)
        return float(np.max(np.abs(d2) / (1 + d1**2) ** 1.5))


def seal_mesh(geometry: SealGeometry | None = None, n_phi: int = 24, n_profile: int = 36, n_thick: int = 1,
              name: str = "boot_seal") -> TetMesh:
    """Structured tetrahedral mesh of the boot seal (see the module docstring).

    `n_phi` cells around, `n_profile` along the meridian (spaced by arc length), `n_thick` through the
    wall; 6 n_phi n_profile n_thick tetrahedra, n_phi (n_profile + 1)(n_thick + 1) nodes.
    """
    g = geometry or SealGeometry()
    g.check()
    if n_phi < 3 or n_profile < 2 or n_thick < 1:
        raise MeshError(f"seal mesh: need n_phi >= 3, n_profile >= 2, n_thick >= 1; got {n_phi}, {n_profile}, {n_thick}")
    # mid-profile by arc length (with cuff/convolution junctions kept as nodes where possible)
    zf = np.linspace(0.0, g.height, 20001)
    Rf = g.profile(zf)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(Rf), np.diff(zf)))])
    sk = np.linspace(0.0, arc[-1], n_profile + 1)
    zk = np.interp(sk, arc, zf)
    zk[0], zk[-1] = 0.0, g.height
    Rk = g.profile(zk)
    # unit normal of the mid-profile (outward: +R for a cylinder)
    dR = np.interp(sk, arc, np.gradient(Rf, arc))
    dZ = np.interp(sk, arc, np.gradient(zf, arc))
    nn = np.hypot(dR, dZ)
    nR, nZ = dZ / nn, -dR / nn
    # keep the cuffs' top/bottom faces flat (horizontal): the normal there is exactly radial
    nR[0] = nR[-1] = 1.0
    nZ[0] = nZ[-1] = 0.0
    eta = np.linspace(-0.5, 0.5, n_thick + 1)
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    # node (i: eta, j: phi, k: profile)
    Rn = Rk[None, :] + eta[:, None] * g.thickness * nR[None, :]  # (ni, nk)
    Zn = zk[None, :] + eta[:, None] * g.thickness * nZ[None, :]
    X = Rn[:, None, :] * np.cos(phi)[None, :, None]
    Y = Rn[:, None, :] * np.sin(phi)[None, :, None]
    Z = np.broadcast_to(Zn[:, None, :], X.shape)
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    nj, nk = n_phi, n_profile + 1

    def nid(i, j, k):
        return (i * nj + (j % nj)) * nk + k

    I, J, K = np.meshgrid(np.arange(n_thick), np.arange(n_phi), np.arange(n_profile), indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    corners = np.column_stack(
        [nid(I + ((c >> 0) & 1), J + ((c >> 1) & 1), K + ((c >> 2) & 1)) for c in range(8)])
    tets = corners[:, _KUHN].reshape(-1, 4)
    vol = tet_signed_volumes(pts, tets)
    # the map (eta, phi, s) -> x has one orientation everywhere for a valid geometry; flip globally
    if np.median(vol) < 0:
        tets[:, [2, 3]] = tets[:, [3, 2]]
    return TetMesh(pts, tets, name=name)


def seal_regions(points: np.ndarray, geometry: SealGeometry | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks of the points (n, 3) in the bottom cuff (z <= cuff) and the top cuff (z >= H - cuff)."""
    g = geometry or SealGeometry()
    tol = 1e-9 * g.height
    z = np.asarray(points)[:, 2]
    return z <= g.cuff + tol, z >= g.height - g.cuff - tol
