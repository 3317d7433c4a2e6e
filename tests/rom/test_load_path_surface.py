"""A load path must lie on the object's surface (issue 16: a user's path 3 mm past the end of a 160 x 60 x 6 mm
plate was accepted silently; one crossing the plate's hole failed during the build with "increase the radius").

`physar.fem.loads.surface_distance` is checked against the analytic distance to a box's and a holed plate's
boundary; `check_load_path` (run by `rom build` before any solve) against paths whose distances from the
plate are known in closed form. The plate's hole is a 20 x 20 mm square (x 70-90 mm, y 20-40 mm) cut from a
structured tet mesh, so the distance of a point over it is its distance to the nearest wall."""
import meshio
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli import rom
from physar.errors import ConfigError
from physar.fem import FESpace
from physar.fem.loads import surface_distance
from physar.geometry import box_mesh
from physar.geometry.mesh import TetMesh
from physar.rom.config import ParameterSection, check_load_path

L, W, H = 0.16, 0.06, 0.006
HOLE = (0.07, 0.09, 0.02, 0.04)      # x0, x1, y0, y1 [m]


def _plate(hole: bool) -> FESpace:
    m = box_mesh((L, W, H), (32, 12, 2))
    if not hole:
        return FESpace(m, "P1")
    x0, x1, y0, y1 = HOLE
    c = m.points[m.cells].mean(1)
    keep = ~((c[:, 0] > x0) & (c[:, 0] < x1) & (c[:, 1] > y0) & (c[:, 1] < y1))
    used, cells = np.unique(m.cells[keep], return_inverse=True)
    return FESpace(TetMesh(m.points[used], cells.reshape(-1, 4)), "P1")


def _box_distance(P):
    """Distance to the boundary of [0, L] x [0, W] x [0, H]: to the nearest face inside, to the box outside."""
    lo, hi = np.zeros(3), np.array([L, W, H])
    inside = np.all((P >= lo) & (P <= hi), 1)
    d_in = np.minimum(P - lo, hi - P).min(1)
    d_out = np.linalg.norm(P - np.clip(P, lo, hi), axis=1)
    return np.where(inside, d_in, d_out)


def _pos(path, radius=0.006, **kw):
    return ParameterSection(name="s", kind="load_position", path=path, load=[0, 0, -8.0], radius=radius, **kw)


@pytest.fixture(scope="module")
def plates():
    return _plate(False), _plate(True)


def test_surface_distance_matches_the_analytic_distance(plates):
    """Random points inside, outside and over the hole: exact to 1e-12 m. Catches: the distance to the
    nearest vertex or face centroid (too large on a face), candidate triangles cut too short (a point far
    from the surface given a farther triangle), a plane distance not clamped to the triangle."""
    box, holed = plates
    rng = np.random.default_rng(0)
    P = rng.uniform([-0.02, -0.02, -0.01], [L + 0.02, W + 0.02, H + 0.01], (400, 3))
    np.testing.assert_allclose(surface_distance(box, P), _box_distance(P), atol=1e-12)
    x0, x1, y0, y1 = HOLE
    Q = np.column_stack([rng.uniform(x0, x1, 200), rng.uniform(y0, y1, 200), np.full(200, H)])
    ref = np.minimum.reduce([Q[:, 0] - x0, x1 - Q[:, 0], Q[:, 1] - y0, y1 - Q[:, 1]])
    np.testing.assert_allclose(surface_distance(holed, Q), ref, atol=1e-12)


def test_a_path_on_the_surface_is_accepted(plates):
    box, holed = plates
    check_load_path(box, _pos([[0.01, 0.03, H], [0.08, 0.045, H], [0.15, 0.03, H]]), "rom.toml")
    check_load_path(holed, _pos([[0.01, 0.01, H], [0.15, 0.01, H]]), "rom.toml")    # beside the hole
    check_load_path(box, _pos([[0.0, 0.03, 0.004], [0.0, 0.03, 0.001]]), "rom.toml")  # on the end face


def test_a_path_point_off_the_object_is_refused_with_its_index_and_distance(plates):
    """3 mm past the end of the plate (radius 6 mm, tol radius / 4 = 1.5 mm): refused naming the file, the
    parameter, the point and its 3 mm; with tol = 4 mm it is the user's choice. Mutants (tried): no check of
    the path points (the sampled check then names no point); tol defaulting to the radius (accepted)."""
    box, _ = plates
    with pytest.raises(ConfigError) as e:
        check_load_path(box, _pos([[0.01, 0.03, H], [0.08, 0.03, H], [L + 0.003, 0.03, H]]), "rom.toml")
    msg = str(e.value)
    assert msg.startswith("rom.toml: [[parameter]] 's': path point 2 [0.163, 0.03, 0.006] is 3 mm from the "
                          "object's surface (tol 1.5 mm)"), msg
    assert "\n" not in msg
    check_load_path(box, _pos([[0.01, 0.03, H], [L + 0.003, 0.03, H]], tol=0.004), "rom.toml")
    with pytest.raises(ConfigError, match=r"path point 0 .* is 2 mm from"):       # inside the 6 mm plate
        check_load_path(box, _pos([[0.01, 0.03, 0.002], [0.15, 0.03, 0.002]]), "rom.toml")


def test_a_path_over_the_hole_is_refused_where_it_leaves_the_object(plates):
    """Both path points on the plate, the line between them over the 20 mm hole: refused saying where the
    path leaves the object (x = 71.5 mm, 1.5 mm past the hole's wall: s = 61.5 mm from x = 10 mm, to one
    sample of 0.75 mm) and comes back (s = 78.5 mm), 10 mm from the surface at its middle, and not to
    increase the radius. Mutant (tried): no sampling between the path points (accepted here; `rom build` then
    fails part way, at the load point over the hole's middle, with a point-load message)."""
    _, holed = plates
    with pytest.raises(ConfigError) as e:
        check_load_path(holed, _pos([[0.01, 0.03, H], [0.15, 0.03, H]]), "rom.toml")
    msg = str(e.value)
    assert msg.startswith("rom.toml: [[parameter]] 's': the path leaves the object at s = "), msg
    leave = float(msg.split("at s = ")[1].split(" mm")[0])
    back = float(msg.split("comes back at s = ")[1].split(" mm")[0])
    assert 60.7 <= leave <= 61.5 and 78.5 <= back <= 79.3, msg
    far = float(msg.split("it is ")[1].split(" mm")[0])
    at = float(msg.split("surface at s = ")[1].split(" mm")[0])
    assert "between path points 0 and 1" in msg and 9.25 <= far <= 10 and 69.25 <= at <= 70.75, msg
    assert "increase the radius" not in msg and "route the path round it" in msg


def test_an_offset_range_that_takes_the_load_off_the_plate_is_refused(plates):
    """A load_offset of up to 15 mm across a path 10 mm from the plate's side edge: 5 mm off, refused naming
    the offset parameter and its end; a range of +/- 8 mm is accepted."""
    box, _ = plates
    pos = _pos([[0.01, 0.05, H], [0.15, 0.05, H]])
    off = ParameterSection(name="o", kind="load_offset", range=[-0.008, 0.015], direction=[0, 1, 0])
    with pytest.raises(ConfigError, match=r"with \[\[parameter\]\] 'o' = 0.015 m the load leaves the object at "
                                          r"s = 0.0 mm \(5 mm from its surface"):
        check_load_path(box, pos, "rom.toml", off)
    ok = ParameterSection(name="o", kind="load_offset", range=[-0.008, 0.008], direction=[0, 1, 0])
    check_load_path(box, pos, "rom.toml", ok)


CONFIG = """
[mesh]
{mesh}

[material]
model = "linear"
E = 3.5e9
nu = 0.36

[[fix]]
plane = {{ point = [0, 0, 0], normal = [1, 0, 0] }}

[[parameter]]
name = "s"
kind = "load_position"
path = {path}
points = 9
load = [0, 0, -8.0]
radius = 0.006
"""


def test_rom_build_refuses_such_paths_in_one_line_before_any_solve(plates, tmp_path):
    """`physar rom build`: exit 2, one `error:` line naming rom.toml and the parameter, nothing written, for
    the path past the end (box mesh) and the path over the hole (the holed plate as a VTU file)."""
    app = typer.Typer()
    rom.register(app)
    _, holed = plates
    meshio.write(tmp_path / "plate.vtu", meshio.Mesh(holed.mesh.points, [("tetra", holed.mesh.cells)]))
    cases = [("box = [0.16, 0.06, 0.006]\ncells = [32, 12, 2]", "[[0.01, 0.03, 0.006], [0.163, 0.03, 0.006]]",
              "'s': path point 1 [0.163, 0.03, 0.006] is 3 mm from"),
             ('file = "plate.vtu"', "[[0.01, 0.03, 0.006], [0.15, 0.03, 0.006]]", "'s': the path leaves the object")]
    for k, (mesh, path, words) in enumerate(cases):
        cfg = tmp_path / f"rom{k}.toml"
        cfg.write_text(CONFIG.format(mesh=mesh, path=path))
        r = CliRunner().invoke(app, ["rom", "build", str(cfg), "--out", str(tmp_path / f"m{k}.npz")])
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert r.exit_code == 2 and "Traceback" not in r.output, r.output
        err = [ln for ln in lines if ln.startswith("error: ")]
        assert len(err) == 1 and err[0].startswith(f"error: {cfg}: [[parameter]] {words}"), r.output
        assert not (tmp_path / f"m{k}.npz").exists()
