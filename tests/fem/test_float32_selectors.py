"""Selectors and probes on float32 meshes (an STL stores float32: a face written at x = 0.16 is read at
0.1599999964, 3.6e-9 m off, while the old default tolerance was 1e-9 of the extent, 1.6e-10 m here)."""

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.fem import FESpace, probe
from physar.fem.config import run_config
from physar.fem.loads import default_tol, select_faces, select_nodes_mask
from physar.geometry import box_mesh, write_mesh
from physar.geometry.mesh import TetMesh

L, W, H = 0.16, 0.04, 0.012
NX, NY, NZ = 8, 2, 2


def _f32_space(element="P2"):
    m = box_mesh((L, W, H), (NX, NY, NZ))
    m = TetMesh(m.points.astype(np.float32).astype(float), m.cells)  # what reading an STL / float32 file gives
    return FESpace(m, element)


def test_float32_rounding_is_outside_the_old_tolerance():
    """The premise: 0.16 in float32 is 3.6e-9 m off, more than 1e-9 of the 0.16 m extent, and within
    default_tol. Catches: a default tol that is still 1e-9 of the extent."""
    off = abs(float(np.float32(L)) - L)
    assert off > 1e-9 * L
    assert off < default_tol(_f32_space().mesh.points) < 1e-5 * L


@pytest.mark.parametrize("element,n_face", [("P1", (NY + 1) * (NZ + 1)), ("P2", (2 * NY + 1) * (2 * NZ + 1))])
def test_plane_at_the_far_face_of_a_float32_box(element, n_face):
    """plane {point = [0.16, 0, 0], normal = [1, 0, 0]} on the float32-rounded box picks exactly the far
    face's nodes, (ny+1)(nz+1) vertices for P1, (2ny+1)(2nz+1) for P2, and nothing of the next layer
    (0.02 m inside); its boundary faces are the 2 ny nz triangles of the face. Also a zero-thickness
    box there. Catches: the 1e-9 x extent default (selects 0 nodes), a tol that reaches the next layer."""
    sp = _f32_space(element)
    m = select_nodes_mask(sp, plane=([L, 0, 0], [1, 0, 0]))
    assert m.sum() == n_face
    assert np.all(np.abs(sp.nodes[m, 0] - L) < 1e-8)
    f = select_faces(sp, plane=([L, 0, 0], [1, 0, 0]))
    assert len(f) == 2 * NY * NZ  # each structured quad of the face is split into 2 triangles
    m = select_nodes_mask(sp, box=[[L, 0, 0], [L, W, H]])
    assert m.sum() == n_face


def test_probe_on_the_boundary_face_of_a_float32_box():
    """A probe at x = 0.16 (on the far face, which is at 0.1599999964) interpolates the nodal field
    (u = x, exact for P1/P2: 0.16); 1 mm outside is still refused. Catches: a barycentric tolerance of
    1e-9 (refuses the face point), a tolerance so large it accepts points outside the part."""
    sp = _f32_space("P2")
    u = np.zeros(sp.n_dofs)
    u[0::3] = sp.nodes[:, 0]
    assert probe(sp, u, [L, 0.0, 0.006])[0] == pytest.approx(L, abs=1e-8)
    assert probe(sp, u, [L, W, H])[0] == pytest.approx(L, abs=1e-8)  # a corner
    with pytest.raises(ConfigError, match="outside the mesh"):
        probe(sp, u, [L + 1e-3, 0.0, 0.006])


def test_stl_plate_plane_fix_and_miss_message(tmp_path):
    """An STL plate (float32) clamped on plane x = 0 and loaded on plane x = 0.16 (the issue-16 case)
    solves; a plane 1 mm beyond the part fails naming the file, the table, the nearest node's distance
    (1e-3 m) and tol. Catches: the default tol on float32, a message without file / table / hint."""
    surf = box_mesh((L, W, H), (4, 1, 1)).boundary().mesh
    write_mesh(tmp_path / "plate.stl", surf)
    text = f"""
[mesh]
file = "plate.stl"
size = 0.01
[material]
model = "linear"
E = 7e10
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
[[load]]
type = "traction"
plane = {{point = [{L}, 0, 0], normal = [1, 0, 0]}}
total = [0, 0, -10.0]
[[probe]]
point = [{L}, 0.0, 0.006]
"""
    toml = tmp_path / "plate.toml"
    toml.write_text(text)
    res = run_config(toml)
    assert res.summary()["probes"][0]["u"][2] < 0
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("plane = {point = [0, 0, 0]", "plane = {point = [-0.001, 0, 0]"))
    with pytest.raises(ConfigError) as e:
        run_config(bad)
    msg = str(e.value)
    assert "bad.toml" in msg and "[[fix]] #1" in msg and "no node matches" in msg
    assert "is 0.001 m from the plane" in msg and "tol" in msg


def test_rom_parameter_plane_on_an_stl_far_face_and_its_miss_message(tmp_path):
    """A rom.toml [[parameter]] displacement on plane x = 0.16 of the STL plate (the issue-16 case) selects
    the far face; at x = 0.161 it fails naming rom.toml, [[parameter]] 'd', the nearest node's 0.001 m and
    tol. Catches: the 1e-9 x extent default, a message without file / parameter / hint."""
    from physar.rom.config import build_rom, load_rom_config

    write_mesh(tmp_path / "plate.stl", box_mesh((L, W, H), (4, 1, 1)).boundary().mesh)
    text = f"""
[mesh]
file = "plate.stl"
size = 0.012
[material]
model = "linear"
E = 7e10
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
[[parameter]]
name = "d"
kind = "displacement"
range = [-0.001, 0.001]
points = 3
direction = [0, 0, 1]
plane = {{point = [{L}, 0, 0], normal = [1, 0, 0]}}
[rom]
method = "pgd"
max_modes = 3
"""
    p = tmp_path / "rom.toml"
    p.write_text(text)
    rom, space, _ = build_rom(load_rom_config(p), source=str(p))
    u = rom.evaluate([0.001]).reshape(-1, 3)
    far = np.abs(space.nodes[:, 0] - L) < 1e-8
    assert far.sum() > 0 and np.allclose(u[far, 2], 0.001)
    p.write_text(text.replace(f"point = [{L}, 0, 0]", "point = [0.161, 0, 0]"))
    with pytest.raises(ConfigError) as e:
        build_rom(load_rom_config(p), source=str(p))
    msg = str(e.value)
    assert "rom.toml" in msg and "[[parameter]] 'd'" in msg and "no node matches plane" in msg
    assert "is 0.001 m from the plane" in msg and "tol" in msg
