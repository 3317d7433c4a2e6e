"""A mesh in millimetres (or microns, or one scaled down twice) read as metres by `physar fem solve`: one
PhysarWarning naming the file and its extent in m (a 100 mm beam read as 100 m deflects 10^6 times too little
under the same load, with no error before). Meshes of 1 mm to 20 m get none. A load box or point that misses
the mesh names the mesh's bounding box (the units mismatch shows)."""

import warnings

import pytest
from typer.testing import CliRunner

from physar.cli.main import app
from physar.errors import ConfigError, PhysarWarning
from physar.fem.config import build_mesh, load_config, run_config
from physar.geometry import box_mesh, write_mesh
from physar.geometry.units import MAX_EXTENT_M, MIN_EXTENT_M

TOML = """
[mesh]
file = "{file}"
{size}
[material]
model = "linear"
E = 7e10
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
[[load]]
type = "traction"
plane = {{point = [{L}, 0, 0], normal = [1, 0, 0]}}
total = [0, 0, {F}]
[fem]
element = "P1"
"""


def _case(tmp_path, scale: float, surface: bool = False) -> tuple:
    """A 0.1 x 0.005 x 0.005 m beam written with coordinates x `scale` (1000: millimetres), loaded by
    100 scale^2 N (the same stress: no displacement warning at any scale)."""
    m = box_mesh((0.1 * scale, 0.005 * scale, 0.005 * scale), (10, 1, 1))
    name = "beam.stl" if surface else "beam.vtu"
    write_mesh(tmp_path / name, m.boundary().mesh if surface else m)
    size = f"size = {0.0025 * scale!r}" if surface else ""
    p = tmp_path / "beam.toml"
    p.write_text(TOML.format(file=name, size=size, L=repr(0.1 * scale), F=repr(-100.0 * scale**2)))
    return p, tmp_path / name


def _solve(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        res = run_config(path)
    return res, [x for x in w if issubclass(x.category, PhysarWarning)]


@pytest.mark.parametrize("surface", [False, True], ids=["vtu", "stl"])
def test_millimetre_mesh_warns_once_naming_file_and_extent(tmp_path, surface):
    """A 100-unit beam (mm): exactly one PhysarWarning, one line, naming beam.vtu / beam.stl, "100 m" and
    "millimetres"; the solve still runs (it is a warning). Mutants caught: no check; the check on the box
    only (file meshes unchecked); a check after tetrahedralize that warns twice (one per mesh)."""
    path, mesh_file = _case(tmp_path, 1000.0, surface)
    _, w = _solve(path)
    assert len(w) == 1, [str(x.message) for x in w]
    msg = str(w[0].message)
    assert "\n" not in msg and str(mesh_file) in msg
    assert "largest extent is 100 m" in msg and "millimetres" in msg and "metres" in msg


def test_micron_and_tiny_meshes_warn(tmp_path):
    """1e5 units (a 0.1 m beam in microns): "microns"; 1e-4 m (metres divided by 1000 twice): "smaller than
    1 mm". Mutants caught: an upper bound only; microns called millimetres."""
    _, w = _solve(_case(tmp_path, 1e6)[0])
    assert len(w) == 1 and "microns" in str(w[0].message) and "1e+05 m" in str(w[0].message)
    _, w = _solve(_case(tmp_path, 1e-3)[0])
    assert len(w) == 1 and "smaller than 1 mm" in str(w[0].message) and "0.0001 m" in str(w[0].message)


@pytest.mark.parametrize("scale", [1.0, 0.011, 199.0])  # 0.1 m, 1.1 mm, 19.9 m
def test_metre_meshes_do_not_warn(tmp_path, scale):
    """Extents 1.1 mm, 0.1 m and 19.9 m (inside [MIN_EXTENT_M, MAX_EXTENT_M] = [1 mm, 20 m]): no warning.
    Mutants caught: thresholds 10x tighter, a warning on every mesh."""
    assert (MIN_EXTENT_M, MAX_EXTENT_M) == (1e-3, 20.0)
    _, w = _solve(_case(tmp_path, scale)[0])
    assert w == []


def test_box_in_millimetres_warns(tmp_path):
    """[mesh] box = [100, 5, 5]: one warning naming "[mesh] box". Mutant caught: file meshes only."""
    p = tmp_path / "box.toml"
    p.write_text(TOML.replace('file = "{file}"\n{size}', "box = [100, 5, 5]\ncells = [4, 1, 1]").format(L=100, F=-1e8))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        build_mesh(load_config(p).mesh, tmp_path)
    assert len(w) == 1 and "[mesh] box = [100.0, 5.0, 5.0]" in str(w[0].message)


def test_cli_prints_one_warning_line(tmp_path):
    """`physar fem solve` on the mm beam: exit 0 and exactly one `warning:` line naming beam.vtu."""
    path, _ = _case(tmp_path, 1000.0)
    r = CliRunner().invoke(app, ["fem", "solve", str(path), "--out", str(tmp_path / "out.vtu")])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(lines) == 1 and "beam.vtu" in lines[0] and "millimetres" in lines[0]


def test_load_box_missing_the_mesh_states_the_mesh_bounds(tmp_path):
    """A traction box in metres ([[0.1, 0, 0], [0.1, 0.005, 0.005]]) on the beam in mm: the one-line error
    names [[load]] #1, the box and the mesh's bounding box [0, 100] x [0, 5] x [0, 5] m with the millimetre
    hint; the same for a [[fix]] box and a point load. Mutants caught: the message without the bounds (as
    before), bounds of the box instead of the mesh."""
    path, _ = _case(tmp_path, 1000.0)
    text = path.read_text()
    bounds = "[0, 100] x [0, 5] x [0, 5] m (largest extent 100 m; it looks like millimetres"
    cases = [
        (text.replace("plane = {point = [100.0, 0, 0], normal = [1, 0, 0]}",
                      "box = [[0.1, 0, 0], [0.1, 0.005, 0.005]]"), "[[load]] #1: traction load: no boundary face"),
        (text.replace("plane = {point = [0, 0, 0], normal = [1, 0, 0]}",
                      "box = [[0.0, 0, 0], [0.0, 0.005, 0.005]]").replace("[[load]]", "[[fix]]\nbox = [[0.1, 0, 0], "
                      "[0.1, 0.005, 0.005]]\n[[load]]"), "[[fix]] #2: no node lies in box"),
        (text.replace('type = "traction"\nplane = {point = [100.0, 0, 0], normal = [1, 0, 0]}',
                      'type = "point"\npoint = [0.1, 0.0025, 0.005]\nradius = 0.002'), "[[load]] #1: point load"),
    ]
    for body, start in cases:
        path.write_text(body)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhysarWarning)
            with pytest.raises(ConfigError) as e:
                run_config(path)
        msg = str(e.value)
        assert "\n" not in msg and start in msg and bounds in msg, msg


def test_plane_selector_miss_on_a_metre_mesh_states_bounds_without_hint(tmp_path):
    """A [[fix]] plane at x = 2 on the 0.1 m beam: the message names the bounds, and no units hint (the mesh
    is in metres). Mutant caught: the millimetre hint on every miss."""
    path, _ = _case(tmp_path, 1.0)
    path.write_text(path.read_text().replace("point = [0, 0, 0]", "point = [2, 0, 0]"))
    with pytest.raises(ConfigError) as e:
        run_config(path)
    msg = str(e.value)
    assert "[[fix]] #1: no node matches plane" in msg and "the mesh spans [0, 0.1] x [0, 0.005] x [0, 0.005] m" in msg
    assert "millimetres" not in msg


def test_same_mesh_read_twice_warns_once(tmp_path):
    """`rom info --check` and `ar run` read a model's [mesh] twice (the model's problem, a check mesh or the
    stress table): the second read does not repeat the warning. Mutant caught: no memo (two warnings)."""
    path, _ = _case(tmp_path, 1000.0)
    cfg = load_config(path)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        build_mesh(cfg.mesh, tmp_path)
        build_mesh(cfg.mesh, tmp_path)
    assert len(w) == 1 and "beam.vtu" in str(w[0].message)
