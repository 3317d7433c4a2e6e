"""`point_to_surface_distance` at any size: trimesh's search tolerances are absolute, so on a part of a few
micrometres the distances read about 2x too far (the review's `denoise --reference` of a 1e-6 m sphere).

Reference (closed form): a point at height h above a face of a convex polyhedron, on the face's normal through
its centroid, is at distance exactly h from the surface (no point of the polyhedron is beyond the face's plane,
and the foot point is on the face)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from physar.geometry.mesh import TriMesh
from physar.geometry.quality import point_to_surface_distance


# mutant caught: the query on the raw coordinates (1e-6 m: errors of tens of percent)
@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1.0, 1e3])
def test_distance_above_faces_is_the_height(scale):
    ico = trimesh.creation.icosphere(subdivisions=2)
    x, f = np.asarray(ico.vertices) * scale, np.asarray(ico.faces)
    tri = x[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    h = rng.uniform(0.001, 0.02, len(f)) * scale
    p = tri.mean(axis=1) + h[:, None] * n
    d = point_to_surface_distance(p, TriMesh(x, f))
    np.testing.assert_allclose(d, h, rtol=1e-6)
