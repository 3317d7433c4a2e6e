"""A probe on the exact (CAD) surface of a curved part lies outside the tet mesh, whose boundary facets are
chords of the curve (the review's case: refused "outside by 5e-5 m" with a tolerance of 1.2e-7 m). It is
snapped to the nearest boundary point when within what the faceted surface may cut inside a curved one there;
a point off a flat face by more than the float32 tolerance, or two element sizes out, is still refused.

The part: a cylinder (radius R = 20 mm, height 60 mm) meshed by physar.geometry.tetrahedralize at 4 mm from a
256-gon (within 3e-6 m of the circle); gmsh meshes the side coarser than asked (32 vertices around the rims,
3.9 mm chords, facet centroids 0.06-0.11 mm inside the circle), the caps at 4 mm. The field u = (x^2 + z, y z, x y) is quadratic, so P2 interpolates it
exactly: a snapped probe must return u at the nearest point of the faceted surface (computed here by
projecting onto the facet's plane), which is also within |grad u| x distance of u at the exact surface point
and close to the nearest node's value.
"""

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.fem import FESpace, probe
from physar.fem.loads import default_tol
from physar.geometry import TriMesh, tetrahedralize

R, HC, N, SIZE = 0.02, 0.06, 256, 0.004
GRAD = 1.01  # bound of |grad u_i| on the part: |(2x, 0, 1)| <= 1.0008, |(0, z, y)| <= 0.064, |(y, x, 0)| <= 0.029


def _field(X):
    X = np.atleast_2d(X)
    return np.column_stack([X[:, 0] ** 2 + X[:, 2], X[:, 1] * X[:, 2], X[:, 0] * X[:, 1]])


@pytest.fixture(scope="module")
def cyl():
    a = np.linspace(0, 2 * np.pi, N, endpoint=False)
    ring = np.column_stack([R * np.cos(a), R * np.sin(a)])
    X = np.vstack([np.column_stack([ring, np.zeros(N)]), np.column_stack([ring, np.full(N, HC)]),
                   [[0, 0, 0], [0, 0, HC]]])
    i, j = np.arange(N), (np.arange(N) + 1) % N
    T = np.vstack([np.column_stack([i, j, N + j]), np.column_stack([i, N + j, N + i]),
                   np.column_stack([np.full(N, 2 * N), j, i]), np.column_stack([np.full(N, 2 * N + 1), N + i, N + j])])
    space = FESpace(tetrahedralize(TriMesh(X, T), size=SIZE), "P2")
    u = _field(space.nodes).ravel()
    surf = space.mesh.boundary()
    tri = surf.mesh.points[surf.mesh.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    return space, u, tri, n


def _side_points(tri, n):
    """For each side facet (normal within 20 deg of radial, away from the rims): the point of the exact
    cylinder radially outward of its centroid, its gap to the facet plane, and its projection onto the facet."""
    c = tri.mean(axis=1)
    rc = np.hypot(c[:, 0], c[:, 1])
    side = (np.abs(n[:, 2]) < np.sin(np.radians(20))) & (c[:, 2] > 2 * SIZE) & (c[:, 2] < HC - 2 * SIZE)
    p = c[side].copy()
    p[:, :2] *= (R / rc[side])[:, None]
    gap = np.einsum("fi,fi->f", p - tri[side, 0], n[side])
    return p, gap, p - gap[:, None] * n[side]


def _edge_h(space):
    X = space.mesh.points[space.mesh.cells]
    return float(np.mean([np.linalg.norm(X[:, a] - X[:, b], axis=1).mean() for a in range(4) for b in range(a + 1, 4)]))


def test_points_on_the_exact_cylinder_are_snapped_to_the_faceted_surface(cyl):
    """Every side facet's outward point on the exact cylinder (gaps up to the facets' sagitta, more than 100x
    the default tol) is accepted; its value is u at the facet point below it (exact for quadratic u, 1e-12),
    within |grad u| x gap of u at the exact point, and within |grad u| x distance of the nearest vertex's value.
    Mutants caught: the old locate (tol only: refused), snapping by clipping the barycentric coordinates of
    the element with the largest signed distance instead of the nearest boundary point (value off)."""
    space, u, tri, n = cyl
    p, gap, q = _side_points(tri, n)
    assert len(p) > 50
    assert gap.max() > 100 * default_tol(space.mesh.points)  # the old tolerance refuses these
    assert gap.min() > 0 and gap.max() < 0.05 * SIZE  # outside, by sagittas
    got = probe(space, u, p)
    assert np.abs(got - _field(q)).max() < 1e-12
    grad = GRAD
    assert np.all(np.abs(got - _field(p)) <= grad * gap[:, None] + 1e-12)
    dist = np.linalg.norm(space.mesh.points[None] - p[:, None], axis=2)
    k = np.argmin(dist, axis=1)
    assert np.all(np.abs(got - _field(space.mesh.points[k])) <= grad * dist[np.arange(len(p)), k][:, None] + 1e-12)


def test_five_sagittas_out_is_refused(cyl):
    """Each side facet's exact-cylinder point moved radially out to 5x its gap (0.3-0.55 mm, far below half an
    element, 1-3 mm): refused, the curved-surface slack is about the facets' sagitta, not a fixed share of the
    element. Mutants caught: slack 5 s instead of 2 s, the sagitta from |x_i - x_j| |n_i - n_j| / 8 (5-7x too
    large on the side's long axial edges)."""
    space, u, tri, n = cyl
    p, gap, _ = _side_points(tri, n)
    radial = np.column_stack([p[:, :2] / R, np.zeros(len(p))])
    for x in p[::8] + 4 * gap[::8, None] * radial[::8]:
        with pytest.raises(ConfigError, match="outside the mesh by"):
            probe(space, u, x)


def test_random_points_on_the_exact_cylinder_are_accepted(cyl):
    """50 random points on the exact side surface (angle, height in the middle two thirds): all accepted,
    each value within |grad u| x (distance to the faceted surface) of the exact field there."""
    space, u, _, _ = cyl
    rng = np.random.default_rng(1)
    a, z = rng.uniform(0, 2 * np.pi, 50), rng.uniform(HC / 6, 5 * HC / 6, 50)
    p = np.column_stack([R * np.cos(a), R * np.sin(a), z])
    got = probe(space, u, p)
    assert np.abs(got - _field(p)).max() < GRAD * 0.05 * SIZE


def test_two_element_sizes_outside_is_refused_in_one_line(cyl):
    """A point 2 h radially outside the cylinder: one ConfigError line "outside the mesh by" with its distance
    (about 2 h). Mutant caught: accepting any distance (snapping without a bound)."""
    space, u, _, _ = cyl
    h = _edge_h(space)
    with pytest.raises(ConfigError) as e:
        probe(space, u, [R + 2 * h, 0.0, HC / 2])
    msg = str(e.value)
    assert "\n" not in msg and "outside the mesh by" in msg
    d = float(msg.split("outside the mesh by ")[1].split(" m")[0])
    assert d == pytest.approx(2 * h, rel=0.02)


def test_flat_cap_and_its_rim_accept_only_the_tolerance(cyl):
    """0.05 h above the flat top cap (at r = R/2) and 0.02 h above it next to the rim (r = 0.97 R, where the
    cap meets the curved side at a 90 deg edge): refused, the cap is flat (the facets are the surface there).
    Mutants caught: accepting SNAP_FRACTION x h everywhere (no curvature estimate), vertex normals that
    average across the sharp rim (FEATURE_ANGLE = 180)."""
    space, u, _, _ = cyl
    h = _edge_h(space)
    for p in ([R / 2, 0.0, HC + 0.05 * h], [0.97 * R * np.cos(0.3), 0.97 * R * np.sin(0.3), HC + 0.02 * h]):
        with pytest.raises(ConfigError, match="outside the mesh by"):
            probe(space, u, p)
    # on the cap within the float32 tolerance: accepted, exact
    p = [R / 2, 0.0, HC + 0.5 * default_tol(space.mesh.points)]
    assert np.allclose(probe(space, u, p), _field([R / 2, 0.0, HC])[0], atol=1e-9)


def test_concave_hole_surface_gets_no_slack():
    """physar's plate with a hole (r = 20 mm, meshed at 6 mm): the hole's facets are chords inside the hole, so
    the exact hole surface is inside the mesh and a point 1e-4 m into the hole beyond a facet (far above the
    3e-7 m tol, below the facets' sagitta, 2.2e-4 m) is outside the part: refused. Mutant caught: the
    sagitta's sign dropped (|(n_i - n_j) . (x_i - x_j)| / 8: 4.4e-4 m of slack on the concave hole too)."""
    from physar.geometry import plate_with_hole_surface

    space = FESpace(tetrahedralize(plate_with_hole_surface(size=0.006), size=0.006), "P1")
    surf = space.mesh.boundary()
    tri = surf.mesh.points[surf.mesh.faces]
    c = tri.mean(axis=1)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    radial = np.column_stack([c[:, 0] - 0.1, c[:, 1] - 0.05, np.zeros(len(c))])
    rc = np.linalg.norm(radial, axis=1)
    hole = np.flatnonzero((rc < 0.021) & (np.einsum("fi,fi->f", n, -radial / rc[:, None]) > 0.95))
    assert len(hole) > 20
    u = np.zeros(space.n_dofs)
    assert 1e-4 > 100 * default_tol(space.mesh.points)
    for f in hole[::4]:
        with pytest.raises(ConfigError, match="outside the mesh by"):
            probe(space, u, c[f] + 1e-4 * n[f])
        probe(space, u, c[f] - 1e-4 * n[f])  # inside the material: accepted
