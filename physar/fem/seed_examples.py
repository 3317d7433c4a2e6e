"""The nonlinear examples of seed 000: the foam beam (§5.2) and the virtual boot seal (§5.3).

Foam beam (§5.2)
    A 797.5 x 200 x 105 mm polyurethane-foam beam, Kirchhoff–Saint Venant law
    W = lambda/2 tr(E)^2 + mu E:E (E Green–Lagrange) with E = 0.11 N/mm^2 = 0.11e6 Pa, nu = 0.2.
    Pinned (u = 0) on the bottom face over its leftmost 40 mm; sliding support (u_z = 0) on the bottom
    face over its rightmost 40 mm. A 15 N lead disk of 80 mm diameter rests centred on the top face at
    x = s (the load position, the reduced model's parameter). The disk is a dead load: a uniform pressure
    p = P / A_disk in -z over the part of the top face covered by the disk,
        f_a = ∫_top p chi_s(x) N_a dA (-e_z),   chi_s(x) = clip((R + w/2 - |x - c_s|) / w, 0, 1),
    with a narrow smoothing band w of the disk edge so that f varies continuously with s, and the
    nodal forces scaled to sum exactly to P. The reference configuration is the beam sagged under its
    own weight (the seed meshed a picture of it), so gravity is not applied again.

Boot seal (§5.3)
    A corrugated rubber sleeve (physar.geometry.seal) with its bottom cuff clamped to the plate and its top
    cuff clamped to a rigid lever that rotates by theta about a pinned axis (the y axis through
    `pivot`). The top-cuff nodes get the prescribed displacement of the rigid rotation
        u_D(X) = R_y(theta) (X - p) + p - X,
    and the seal follows the nearly incompressible neo-Hookean law W = C1 (Ī1 - 3) + kappa/2 (J - 1)^2
    (physar.fem.NeoHookeanIncompressible; the seed's W = C1 (I1 - 3) in the limit kappa -> inf).
    The seed gives C1 = 1166 MPa. With prescribed displacements only (no applied forces) the
    equilibrium displacement does not depend on the scale of C1 (the equations are homogeneous of
    degree one in (C1, kappa)): only the ratio kappa / C1 matters, and stresses scale with C1.
    The solve over theta is a continuation: theta is raised in increments, each increment solved by
    Newton from the previous equilibrium, and an increment that fails is halved (load stepping in theta).

Units: SI (m, N, Pa, rad) throughout.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from physar.errors import ConfigError, SolverError
from physar.fem.assembly import ElasticModel
from physar.fem.elements import FESpace, shape_functions
from physar.fem.loads import fixed_dofs
from physar.fem.materials import LinearElastic, NeoHookeanIncompressible, StVK
from physar.fem.post import probe, von_mises
from physar.fem.solvers import StaticResult, factorize, solve_static
from physar.geometry.mesh import TET_FACES, TetMesh, box_mesh

# ------------------------------------------------------------------------------------------------
# disk load
# ------------------------------------------------------------------------------------------------


def _lattice(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the k^2 congruent sub-triangles of the reference triangle: barycentric (k^2, 3)
    and equal weights summing to 1 (midpoint rule on each sub-triangle)."""
    pts = []
    for i in range(k):
        for j in range(k - i):
            pts.append(((i + 1 / 3) / k, (j + 1 / 3) / k))
            if i + j <= k - 2:
                pts.append(((i + 2 / 3) / k, (j + 2 / 3) / k))
    xy = np.array(pts)
    L = np.column_stack([1.0 - xy.sum(axis=1), xy])
    return L, np.full(len(L), 1.0 / len(L))


def disk_load(
    space: FESpace,
    center: Sequence[float],
    radius: float,
    total: float,
    normal: Sequence[float] = (0.0, 0.0, 1.0),
    direction: Sequence[float] = (0.0, 0.0, -1.0),
    band: float | None = None,
    subdivisions: int = 8,
) -> np.ndarray:
    """Nodal forces (n_dofs,) [N] of a disk of `radius` [m] pressing with force `total` [N] along
    `direction` on the boundary faces facing `normal` (outward normal within 30 deg), centred at `center`.

    Uniform pressure over the covered area with the edge smoothed over a band `band` [m] (default: a
    tenth of the radius); each face is integrated on a lattice of `subdivisions`^2 sub-triangles; the
    forces sum exactly to `total` (seed 000 §5.2: lead disks of 80 mm diameter, 15 N).
    """
    if not (np.isfinite(radius) and radius > 0):
        raise ConfigError(f"disk load radius must be positive, got {radius}")
    if not (np.isfinite(total) and total >= 0):
        raise ConfigError(f"disk load total must be >= 0, got {total}")
    band = 0.1 * radius if band is None else float(band)
    if not band > 0:
        raise ConfigError(f"disk load band must be positive, got {band}")
    c = np.asarray(center, dtype=float)
    nrm = np.asarray(normal, dtype=float)
    nrm = nrm / np.linalg.norm(nrm)
    dirv = np.asarray(direction, dtype=float)
    dirv = dirv / np.linalg.norm(dirv)
    cache = space.__dict__.setdefault("_physar_cache", {})
    if "boundary" not in cache:
        cache["boundary"] = space.mesh.boundary()
    surf = cache["boundary"]
    pts_face = surf.mesh.points[surf.mesh.faces]  # (F, 3, 3)
    cen = pts_face.mean(axis=1)
    reach = np.linalg.norm(pts_face - cen[:, None], axis=2).max(axis=1)
    facing = surf.mesh.face_normals() @ nrm > np.cos(np.radians(30))
    # distance in the plane of the disk
    d_plane = cen - c
    d_plane = d_plane - np.outer(d_plane @ nrm, nrm)
    near = facing & (np.linalg.norm(d_plane, axis=1) <= radius + band + reach) & (
        np.abs((cen - c) @ nrm) <= 2 * reach.max() + 1e-12)
    faces = np.flatnonzero(near)
    if len(faces) == 0:
        raise ConfigError(f"disk load at {c.tolist()}: no boundary face facing {nrm.tolist()} under the disk")
    Lt, wt = _lattice(int(subdivisions))
    verts = TET_FACES[surf.face_local[faces]]
    cells = surf.face_cell[faces]
    Ltet = np.zeros((len(faces), len(wt), 4))
    for j in range(3):
        Ltet[np.arange(len(faces))[:, None], :, verts[:, j: j + 1]] = Lt[None, :, j]
    N = shape_functions(space.element, Ltet)  # (f, q, nen)
    x = np.einsum("fqa,fai->fqi", Ltet, space.mesh.points[space.mesh.cells[cells]])
    r = x - c
    r = r - np.einsum("fqi,i->fq", r, nrm)[..., None] * nrm
    chi = np.clip((radius + 0.5 * band - np.linalg.norm(r, axis=2)) / band, 0.0, 1.0)
    area = surf.mesh.face_areas()[faces]
    k = chi * area[:, None] * wt[None, :]
    if k.sum() <= 0:
        raise ConfigError(f"disk load at {c.tolist()}: the disk covers no boundary face")
    nodal = np.einsum("fq,fqa,i->fai", k / k.sum(), N, total * dirv)
    dofs = space.cell_dofs[cells]
    return np.bincount(dofs.ravel(), weights=nodal.reshape(len(cells), -1).ravel(), minlength=space.n_dofs)


# ------------------------------------------------------------------------------------------------
# foam beam
# ------------------------------------------------------------------------------------------------

FOAM_SIZE = (0.7975, 0.200, 0.105)  # m
FOAM_E = 0.11e6  # Pa (0.11 N/mm^2)
FOAM_NU = 0.2
FOAM_DISK_LOAD = 15.0  # N
FOAM_DISK_RADIUS = 0.040  # m (80 mm diameter)
FOAM_SUPPORT = 0.040  # m, pinned length on the left, sliding length on the right
FOAM_MARGIN = 0.100  # m, ends of the beam outside the load range (seed: 100 mm not considered)


def _graded_axis(length: float, n: int, support: float) -> np.ndarray:
    """n + 1 increasing coordinates on [0, length] with nodes at `support` and `length - support`."""
    h = length / n
    ns = max(1, int(round(support / h)))  # noqa: RUF046 - numpy 1.x round
    nm = n - 2 * ns
    if nm < 1:
        raise ConfigError(f"foam beam: {n} cells along x are too few (need more than {2 * ns})")
    return np.concatenate([
        np.linspace(0.0, support, ns + 1),
        np.linspace(support, length - support, nm + 1)[1:],
        np.linspace(length - support, length, ns + 1)[1:],
    ])


def foam_mesh(cells: Sequence[int] = (32, 8, 4), size: Sequence[float] = FOAM_SIZE,
              support: float = FOAM_SUPPORT) -> TetMesh:
    """Structured tet mesh of the foam beam with node planes at x = support and x = L - support."""
    L, W, H = map(float, size)
    cells = tuple(int(c) for c in cells)
    base = box_mesh((L, W, H), cells)
    xs = _graded_axis(L, cells[0], support)
    u = np.linspace(0.0, L, cells[0] + 1)
    pts = base.points.copy()
    pts[:, 0] = np.interp(pts[:, 0], u, xs)
    return TetMesh(pts, base.cells, name=f"foam_beam{cells}")


@dataclass
class FoamBeam:
    """The foam beam of seed 000 §5.2 on an FE space; `solve(s)` gives the displacement under the disk at x = s.

    Attributes: `space`, `model` (St.VK), `fixed` (pinned left + sliding right), `size` (L, W, H) [m],
    `load` [N], `radius` [m], `s_range` (s_min, s_max) [m].
    """

    space: FESpace
    model: ElasticModel
    fixed: np.ndarray
    size: tuple[float, float, float]
    load: float = FOAM_DISK_LOAD
    radius: float = FOAM_DISK_RADIUS
    margin: float = FOAM_MARGIN
    steps: int = 4
    E: float = FOAM_E
    nu: float = FOAM_NU

    @property
    def s_range(self) -> tuple[float, float]:
        return (self.margin, self.size[0] - self.margin)

    def load_vector(self, s: float, load: float | None = None) -> np.ndarray:
        """Nodal forces [N] of the disk centred on the top face at x = s [m]."""
        L, W, H = self.size
        s = float(s)
        if not (0.0 <= s <= L):
            raise ConfigError(f"foam beam: load position s = {s} m outside the beam [0, {L}]")
        return disk_load(self.space, (s, W / 2, H), self.radius, self.load if load is None else load)

    def solve(self, s: float, load: float | None = None, steps: int | None = None,
              u0: np.ndarray | None = None, tol: float = 1e-9,
              progress: Callable[[int, int], None] | None = None) -> StaticResult:
        """Nonlinear (St.VK) equilibrium under the disk at x = s; Newton with `steps` load steps."""
        f = self.load_vector(s, load)
        return solve_static(self.model, f, self.fixed, steps=steps or self.steps, u0=u0, tol=tol,
                            progress=progress)

    @cached_property
    def linear_model(self) -> ElasticModel:
        """The small-strain linear elastic model with the same E, nu (the limit of small loads)."""
        return ElasticModel(self.space, LinearElastic(self.E, self.nu))

    def solve_linear(self, s: float, load: float | None = None) -> np.ndarray:
        return solve_static(self.linear_model, self.load_vector(s, load), self.fixed).u

    def top_centerline(self, n: int = 41) -> np.ndarray:
        """Reference points (n, 3) on the top face along the beam axis (y = W/2, z = H) [m]."""
        L, W, H = self.size
        x = np.linspace(0.0, L, n)
        return np.column_stack([x, np.full(n, W / 2), np.full(n, H)])

    def deflection(self, u: np.ndarray, x: float) -> float:
        """Deflection -u_z [m] at (x, W/2, H/2) (mid-depth, mid-height)."""
        _L, W, H = self.size
        return float(-probe(self.space, u, [x, W / 2, H / 2])[2])


def foam_beam(cells: Sequence[int] = (32, 8, 4), element: str = "P1", E: float = FOAM_E, nu: float = FOAM_NU,
              load: float = FOAM_DISK_LOAD, radius: float = FOAM_DISK_RADIUS, size: Sequence[float] = FOAM_SIZE,
              support: float = FOAM_SUPPORT, steps: int = 4) -> FoamBeam:
    """Build the foam beam of seed 000 §5.2 (see the module docstring for the model)."""
    size = tuple(float(v) for v in size)
    if len(size) != 3 or min(size) <= 0:
        raise ConfigError(f"foam beam: size must be three positive lengths [m], got {list(size)}")
    if not 0 < support < size[0] / 2:
        raise ConfigError(f"foam beam: support length {support} must be in (0, L/2)")
    mesh = foam_mesh(cells, size, support)
    space = FESpace(mesh, element)
    model = ElasticModel(space, StVK(E, nu))
    L, W, _H = size
    tol = 1e-9 * L
    pinned = fixed_dofs(space, box=[[0, 0, 0], [support, W, 0]], components="xyz")
    sliding = fixed_dofs(space, where=lambda X: (X[:, 2] <= tol) & (X[:, 0] >= L - support - tol), components="z")
    fixed = np.union1d(pinned, sliding)
    return FoamBeam(space, model, fixed, size, float(load), float(radius), steps=int(steps), E=float(E),
                    nu=float(nu))


# ------------------------------------------------------------------------------------------------
# boot seal
# ------------------------------------------------------------------------------------------------

SEAL_C1 = 1166e6  # Pa (seed 000 §5.3; see the module docstring: the scale does not change displacements)
SEAL_KAPPA_RATIO = 200.0  # kappa / C1: small-strain Poisson ratio (3K - 2 mu) / (6K + 2 mu) = 0.495
SEAL_THETA_MAX = np.radians(52.0)


def rotation_y(theta: float) -> np.ndarray:
    """Rotation matrix about +y by `theta` [rad] (x towards -z for theta > 0)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass
class BootSeal:
    """The virtual boot seal of seed 000 §5.3 on an FE space.

    `bottom`, `top`: node indices of the clamped cuffs; `fixed`: their dofs; `pivot` [m]: a point of the
    lever's rotation axis (the y direction). `solve(theta)` follows the lever from 0 to theta [rad].
    """

    space: FESpace
    model: ElasticModel
    geometry: object
    bottom: np.ndarray
    top: np.ndarray
    pivot: np.ndarray
    fixed: np.ndarray = field(init=False)
    theta_max: float = SEAL_THETA_MAX

    def __post_init__(self):
        nodes = np.concatenate([self.bottom, self.top])
        self.fixed = np.sort((3 * nodes[:, None] + np.arange(3)).ravel())

    def prescribed(self, theta: float, rotate_bottom: bool = False) -> np.ndarray:
        """u_D (n_dofs,): the top cuff rotated rigidly by `theta` [rad] about the lever axis, the bottom
        cuff at rest (or, with `rotate_bottom`, rotated too: a rigid motion of the whole seal)."""
        X = self.space.nodes
        Rm = rotation_y(theta)
        u = np.zeros_like(X)
        ids = np.concatenate([self.top, self.bottom]) if rotate_bottom else self.top
        u[ids] = (X[ids] - self.pivot) @ Rm.T + self.pivot - X[ids]
        return u.ravel()

    def solve(self, theta: float, u0: np.ndarray | None = None, theta0: float = 0.0, increment: float | None = None,
              tol: float = 1e-9, max_halvings: int = 8, rotate_bottom: bool = False,
              progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, dict]:
        """Equilibrium at lever angle `theta` [rad] by continuation from (theta0, u0) (default the rest state).

        theta goes up in increments of at most `increment` (default 4 deg); each increment is one Newton
        solve (physar.fem.solve_static) from the previous equilibrium with the exact rigid rotation of the
        cuff as the Dirichlet value; a failed increment is halved (up to `max_halvings` times).
        Returns (u, info) with info["angles"] (the accepted angles) and info["newton_iterations"].
        """
        theta = float(theta)
        inc = np.radians(4.0) if increment is None else float(increment)
        if not inc > 0:
            raise ConfigError(f"seal: theta increment must be positive, got {inc}")
        u = np.zeros(self.space.n_dofs) if u0 is None else np.array(u0, dtype=float)
        t = float(theta0)
        angles, iters = [], []
        sign = 1.0 if theta >= t else -1.0
        h = inc
        halvings = 0
        n_total = max(1, int(np.ceil(abs(theta - t) / inc)))
        while abs(theta - t) > 1e-14:
            t_new = t + sign * min(h, abs(theta - t))
            try:
                u_d = self.prescribed(t_new, rotate_bottom)
                res = solve_static(self.model, np.zeros(self.space.n_dofs), self.fixed, steps=1,
                                   u0=self._predict(u, u_d), tol=tol, prescribed=u_d)
            except SolverError:
                halvings += 1
                if halvings > max_halvings:
                    raise SolverError(
                        f"boot seal: Newton failed at theta = {np.degrees(t_new):.3f} deg even with increments of "
                        f"{np.degrees(h):.4f} deg; refine the mesh or lower kappa") from None
                h /= 2
                continue
            u, t = res.u, t_new
            angles.append(t)
            iters.append(res.newton_iterations[0])
            if progress:
                progress(min(len(angles), n_total), n_total)
            h = min(inc, 2 * h)  # grow back after a success
        return u, {"angles": angles, "newton_iterations": iters, "halvings": halvings}

    def _predict(self, u: np.ndarray, u_d: np.ndarray) -> np.ndarray:
        """Predictor for a Dirichlet increment: the tangent at the last equilibrium u carried to the new
        cuff position, K_ff(u) du_f = -(f_int(u) + K_fd(u) du_d)_f (a Newton step taken at the converged
        state, where K is positive definite; Newton from the raw jump of the cuff nodes alone starts in an
        indefinite, badly distorted state)."""
        free = self._free
        du = np.zeros_like(u)
        du[self.fixed] = u_d[self.fixed] - u[self.fixed]
        K = self.model.tangent_stiffness(u)
        r = self.model.internal_force(u) + K @ du
        du[free] = -factorize(K[free][:, free]).solve(r[free])
        return u + du

    @cached_property
    def _free(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.space.n_dofs), self.fixed)

    def sweep(self, thetas: Sequence[float], increment: float | None = None, tol: float = 1e-9,
              progress: Callable[[int, int], None] | None = None) -> np.ndarray:
        """Snapshots (len(thetas), n_dofs) along increasing angles [rad] by one continuation."""
        thetas = np.asarray(thetas, dtype=float)
        if np.any(np.diff(thetas) < 0):
            raise ConfigError("seal sweep: angles must be increasing")
        out = np.zeros((len(thetas), self.space.n_dofs))
        u, t = None, 0.0
        for q, th in enumerate(thetas):
            u, _ = self.solve(th, u0=u, theta0=t, increment=increment, tol=tol)
            t = th
            out[q] = u
            if progress:
                progress(q + 1, len(thetas))
        return out

    def lever_moment(self, u: np.ndarray) -> float:
        """Moment [N m] about the lever axis (+y through `pivot`) that the lever exerts on the seal:
        M = sum over top-cuff nodes of ((x - p) x r)_y, with r the nodal reaction f_int and x = X + u."""
        f = self.model.internal_force(u).reshape(-1, 3)[self.top]
        x = self.space.nodes[self.top] + u.reshape(-1, 3)[self.top] - self.pivot
        return float(np.cross(x, f)[:, 1].sum())

    def von_mises(self, u: np.ndarray) -> np.ndarray:
        return von_mises(self.model, u)


def boot_seal(geometry=None, n_phi: int = 24, n_profile: int = 36, n_thick: int = 1, element: str = "P2",
              C1: float = SEAL_C1, kappa: float | None = None, pivot: Sequence[float] = (0.0, 0.0, 0.0)) -> BootSeal:
    """Build the boot seal of seed 000 §5.3 (mesh by physar.geometry.seal; see the module docstring).

    `kappa` defaults to SEAL_KAPPA_RATIO * C1. `pivot` [m] is a point of the lever axis (direction y);
    the default, the plate's centre, puts the lever's pivot at the seal's base.
    """
    from physar.geometry.seal import SealGeometry, seal_mesh, seal_regions

    g = geometry or SealGeometry()
    mesh = seal_mesh(g, n_phi=n_phi, n_profile=n_profile, n_thick=n_thick)
    space = FESpace(mesh, element)
    kappa = SEAL_KAPPA_RATIO * C1 if kappa is None else float(kappa)
    model = ElasticModel(space, NeoHookeanIncompressible(C1=float(C1), kappa=kappa))
    bot, top = seal_regions(space.nodes, g)
    return BootSeal(space, model, g, np.flatnonzero(bot), np.flatnonzero(top), np.asarray(pivot, dtype=float))
