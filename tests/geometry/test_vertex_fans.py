"""A surface whose parts touch at a single vertex (a bow tie: two closed boxes sharing one corner) is refused in
one line naming the vertex: README's "non-manifold input gives a one-line error" checked edges only, and the
two-stage filter moved a tiny bow tie's vertices 12 m on a 1 m part.

References: trimesh's boxes joined at the corner (1, 1, 1) / 2 by hand (15 vertices, the shared one has two
fans); trimesh's icosphere (one fan at every vertex); an open cap of it (one fan at every used vertex, none at
the unused ones)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from physar.cli.main import app
from physar.errors import MeshError
from physar.geometry.mesh import TriMesh
from physar.geometry.quality import check_surface, vertex_fans


def _bowtie():
    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([1, 1, 1])
    m = trimesh.util.concatenate([a, b])
    m.merge_vertices()
    return np.asarray(m.vertices), np.asarray(m.faces)


# mutants caught: fans counted per face instead of per edge-connected group (every vertex > 1), the wedge of the
# wrong end of an edge joined (the icosphere's fans split)
def test_fans_by_hand():
    ico = trimesh.creation.icosphere(subdivisions=2)
    x, f = np.asarray(ico.vertices), np.asarray(ico.faces)
    assert (vertex_fans(TriMesh(x, f)) == 1).all()
    cap = f[x[f].mean(axis=1)[:, 2] > 0.3]
    fans = vertex_fans(TriMesh(x, cap))
    used = np.zeros(len(x), bool)
    used[cap.ravel()] = True
    assert (fans[used] == 1).all() and (fans[~used] == 0).all()
    x, f = _bowtie()
    fans = vertex_fans(TriMesh(x, f))
    corner = int(np.flatnonzero(np.all(np.isclose(x, 0.5), axis=1))[0])
    assert len(x) == 15 and fans[corner] == 2 and (np.delete(fans, corner) == 1).all()


def test_bowtie_refused_in_one_line(tmp_path):
    x, f = _bowtie()
    with pytest.raises(MeshError, match=r"non-manifold vertex \d+ at \[0.5, 0.5, 0.5\]: its faces form 2 fans"):
        check_surface(TriMesh(x, f, name="bowtie"))
    trimesh.Trimesh(x * 1e-3, f, process=False).export(tmp_path / "bowtie.obj")
    r = CliRunner().invoke(app, ["denoise", str(tmp_path / "bowtie.obj"), "--out", str(tmp_path / "d.obj")])
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert r.exit_code == 2 and len(errors) == 1 and "non-manifold vertex" in errors[0], r.output
    assert not (tmp_path / "d.obj").exists()
