"""Small test surfaces shared by several test modules."""
import numpy as np
import trimesh

from physar.geometry.mesh import TriMesh


def hemisphere() -> TriMesh:
    """Open cap: the faces of trimesh's 642-vertex unit icosphere above z = 0 (337 vertices)."""
    t = trimesh.creation.icosphere(subdivisions=3)
    x, f = np.asarray(t.vertices), np.asarray(t.faces)
    cap = f[x[f].mean(axis=1)[:, 2] > 0]
    used = np.unique(cap)
    remap = np.full(len(x), -1)
    remap[used] = np.arange(len(used))
    return TriMesh(x[used], remap[cap], name="hemisphere")
