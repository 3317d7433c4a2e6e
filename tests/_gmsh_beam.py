"""The beam of the surface-tag tests, meshed by gmsh: shared by tests/geometry/test_surface_tags.py and
tests/fem/test_surface_tags_solve.py (imported as ``_gmsh_beam``: pytest puts tests/, the folder of the root
conftest.py, on sys.path)."""

from __future__ import annotations

import numpy as np

L, W, H = 0.2, 0.02, 0.02  # the beam [0, L] x [0, W] x [0, H] (m)
NAMES = {"clamp": (1, 2), "load": (2, 2), "rest": (3, 2)}


def gmsh_beam_surface(path, version=4.1, size=0.01):
    """The closed surface of the beam meshed by gmsh (OpenCASCADE box, its volume removed: a surface model)
    with physical groups 'clamp' (x = 0, tag 1), 'load' (x = L, tag 2) and 'rest' (the four sides, tag 3),
    written by gmsh. Returns gmsh's own triangles of each group as sets of rounded vertex coordinates."""
    from physar.geometry.tetra import _Gmsh

    with _Gmsh() as g:
        g.model.add("beam")
        v = g.model.occ.addBox(0, 0, 0, L, W, H)
        g.model.occ.synchronize()
        x = {t: g.model.occ.getCenterOfMass(2, t)[0] for _, t in g.model.getEntities(2)}
        g.model.occ.remove([(3, v)])
        g.model.occ.synchronize()
        groups = {"clamp": [t for t, c in x.items() if np.isclose(c, 0)],
                  "load": [t for t, c in x.items() if np.isclose(c, L)]}
        groups["rest"] = [t for t in x if t not in groups["clamp"] + groups["load"]]
        for name, (tag, dim) in NAMES.items():
            g.model.addPhysicalGroup(dim, groups[name], tag, name=name)
        g.option.setNumber("Mesh.MeshSizeMax", size)
        g.option.setNumber("Mesh.MshFileVersion", version)
        g.model.mesh.generate(2)
        tags, coords, _ = g.model.mesh.getNodes()
        xyz = dict(zip(tags.tolist(), np.asarray(coords).reshape(-1, 3).tolist(), strict=True))
        ref = {}
        for name, ents in groups.items():
            ref[name] = set()
            for t in ents:
                _, nodes = g.model.mesh.getElementsByType(2, t)
                ref[name] |= {frozenset(tuple(np.round(xyz[n], 12)) for n in tri)
                              for tri in np.asarray(nodes).reshape(-1, 3).tolist()}
        g.write(str(path))
    return ref
