"""Notebook-friendly reprs: one short line per data object, no arrays, with counts and ranges that match
independent counts (closed-form node/element counts of a structured box, focal lengths and rotation angles
computed by hand here), and a clean ``dir(physar)``.

Every repr is checked to be one line of at most ``MAX_CHARS`` characters without ``array(`` / ``tensor(``
(:func:`short`), including for a mesh of ~200k tetrahedra.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp

from physar.fem import ElasticModel, FESpace, LinearElastic, StaticResult, traction_load
from physar.fem.config import FemResult, Problem
from physar.geometry import MeshTags, TetMesh, box_mesh
from physar.integrators import Ground, LinearDynamics, SolidModel, State, make_integrator
from physar.integrators.config import Trajectory
from physar.integrators.model import Linearization
from physar.integrators.steppers import StepStats
from physar.rom import SeparatedModel
from physar.rom.pgd import SeparatedTerm
from physar.rom.problem import Modulus, MovingLoad, ParametricProblem, Rotation, Translation
from physar.rom.quality import DiscretisationCheck
from physar.vision import Camera, Pose

MAX_CHARS = 300
NUM = r"(-?[0-9.]+(?:e[+-]?\d+)?)"


def short(obj) -> str:
    """repr(obj), asserted to be one line of at most MAX_CHARS characters with no array or tensor dump."""
    r = repr(obj)
    assert "\n" not in r and len(r) <= MAX_CHARS, r
    assert "array(" not in r and "tensor(" not in r and "object at 0x" not in r, r
    assert r.startswith(type(obj).__name__ + "("), r
    return r


def number(text: str, pattern: str) -> float:
    """The number that `pattern` (with one NUM group) finds in `text`."""
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not in {text!r}"
    return float(m.group(1))


def box_text(text: str) -> list[tuple[float, float]]:
    """The [lo, hi] x [lo, hi] x [lo, hi] of a summary."""
    pairs = re.findall(rf"\[{NUM}, {NUM}\]", text.split("bounds ")[1])
    return [(float(a), float(b)) for a, b in pairs[:3]]


# --- geometry -----------------------------------------------------------------------------------------

N = (12, 7, 5)


def box_counts(nx, ny, nz):
    """Closed forms of the structured box: nodes, Kuhn tetrahedra (6 per hexahedron), boundary nodes and
    boundary triangles (2 per boundary quad)."""
    nodes = (nx + 1) * (ny + 1) * (nz + 1)
    interior = (nx - 1) * (ny - 1) * (nz - 1)
    return nodes, 6 * nx * ny * nz, nodes - interior, 4 * (nx * ny + ny * nz + nz * nx)


@pytest.fixture(scope="module")
def mesh():
    return box_mesh((2.0, 1.0, 0.5), N, origin=(-1.0, 2.0, 3.0))


def test_tetmesh_counts_and_bounds(mesh):
    r = short(mesh)
    nodes, tets, _, _ = box_counts(*N)
    assert number(r, rf"{NUM} nodes") == nodes == 624
    assert number(r, rf"{NUM} tetrahedra") == tets == 2520
    assert box_text(r) == [(-1.0, 1.0), (2.0, 3.0), (3.0, 3.5)]
    assert r.endswith(" m)") and repr(mesh.name) in r


def test_tetmesh_big_mesh_stays_short():
    big = box_mesh((1.0, 1.0, 1.0), (40, 30, 30))
    r = short(big)
    assert number(r, rf"{NUM} tetrahedra") == 6 * 40 * 30 * 30
    assert number(r, rf"{NUM} nodes") == 41 * 31 * 31


def test_tetmesh_names_its_regions():
    base = box_mesh((1.0, 1.0, 1.0), (1, 1, 1))
    tags = MeshTags(cell_tags=np.ones(base.n_cells, np.int64), names={"steel": (1, 3), "top": (2, 2)})
    r = short(TetMesh(base.points, base.cells, name="part", tags=tags))
    assert r.startswith("TetMesh('part', 8 nodes, 6 tetrahedra") and "regions steel, top" in r


def test_boundary_and_trimesh_counts(mesh):
    _, _, bnodes, btris = box_counts(*N)
    b = mesh.boundary()
    for r in (short(b), short(b.mesh)):
        assert number(r, rf"{NUM} nodes") == bnodes
        assert number(r, rf"{NUM} triangles") == btris
        assert box_text(r) == [(-1.0, 1.0), (2.0, 3.0), (3.0, 3.5)]
    assert short(b).endswith(" m)") and not short(b.mesh).endswith(" m)")  # a surface file's unit is unknown


# --- fem ----------------------------------------------------------------------------------------------

def test_fespace_counts(mesh):
    nodes, tets, _, btris = box_counts(*N)
    faces = (4 * tets + btris) // 2  # each interior face shared by two tetrahedra
    edges = nodes + faces - tets - 1  # Euler: V - E + F - T = 1 for a ball
    for element, n_nodes in (("P1", nodes), ("P2", nodes + edges)):
        r = short(FESpace(mesh, element))
        assert r.startswith(f"FESpace({element} on ")
        assert number(r, rf"{NUM} tetrahedra") == tets
        assert number(r, rf"{NUM} nodes") == n_nodes
        assert number(r, rf"{NUM} dofs") == 3 * n_nodes


def test_elastic_model_problem_and_results():
    m = box_mesh((1.0, 0.2, 0.2), (5, 2, 2))
    space = FESpace(m, "P1")
    model = ElasticModel(space, LinearElastic(69e9, 0.33), density=2700.0)
    r = short(model)
    assert "LinearElastic(E=69000000000.0, nu=0.33)" in r and "density 2700 kg/m^3" in r
    assert number(r, rf"{NUM} dofs") == 3 * 6 * 3 * 3 and number(r, rf"{NUM} tetrahedra") == 6 * 5 * 2 * 2

    f = traction_load(space, [[1, 0, 0], [1, 0.2, 0.2]], [0.0, 0.0, -1000.0])
    fixed = np.arange(27)  # the 9 nodes of the x = 0 face: 27 dofs
    problem = Problem(space, model, f, fixed, np.zeros((2, 3)), config=None)
    r = short(problem)
    assert "27 fixed dofs" in r and "2 probes" in r
    assert re.search(rf"total load \[{NUM}, {NUM}, {NUM}\] N", r).groups() == ("0", "0", "-1000")

    u = np.zeros(space.n_dofs)
    u[[3, 4]] = 3.0, 4.0  # node 1: |u| = 5
    res = StaticResult(u, newton_iterations=[2, 3], converged=False)
    r = short(res)
    assert "not converged" in r and "2 load steps" in r and "5 Newton iterations" in r
    assert number(r, rf"max \|u\| {NUM} m") == 5.0 and number(r, rf"{NUM} dofs") == space.n_dofs
    vm = np.linspace(0.0, 2.5e6, space.mesh.n_cells)
    r = short(FemResult(problem, res, vm))
    assert number(r, rf"max von Mises {NUM} Pa") == 2.5e6 and number(r, rf"max \|u\| {NUM} m") == 5.0


# --- vision -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("w, h, fov", [(640, 480, 60.0), (1920, 1080, 90.0), (64, 48, 30.0)])
def test_camera_from_fov(w, h, fov):
    r = short(Camera.from_fov(w, h, fov))
    f = (w / 2) / math.tan(math.radians(fov) / 2)  # by hand
    assert r.startswith(f"Camera({w}x{h}, ")
    assert number(r, rf"fx={NUM}") == pytest.approx(f, abs=0.05)
    assert number(r, rf"fy={NUM}") == pytest.approx(f, abs=0.05)
    assert number(r, rf"cx={NUM}") == pytest.approx((w - 1) / 2, abs=0.05)
    assert number(r, rf"cy={NUM}") == pytest.approx((h - 1) / 2, abs=0.05)
    assert r.endswith("dist=none)")


def test_camera_distortion_listed():
    K = np.array([[800.0, 0, 330], [0, 790, 250], [0, 0, 1]])
    r = short(Camera(K, [0.1, -0.02, 0.001, 0.0, 0.003], 640, 480))
    assert r == "Camera(640x480, fx=800.0, fy=790.0, cx=330.0, cy=250.0, dist=[0.1, -0.02, 0.001, 0, 0.003])"


def rodrigues(axis, deg):
    """R = I + sin(a) [k]x + (1 - cos(a)) [k]x^2 (written out here, not cv2)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx


@pytest.mark.parametrize("deg, axis", [(37.0, (1, 2, 2)), (120.0, (0, 0, -1)), (179.0, (3, 0, 4))])
def test_pose_angle_axis_translation(deg, axis):
    r = short(Pose(rodrigues(axis, deg), [0.1, -0.25, 1.5]))
    assert number(r, rf"rotation {NUM} deg") == pytest.approx(deg, abs=1e-3)
    got = [float(v) for v in re.search(rf"about \[{NUM}, {NUM}, {NUM}\]", r).groups()]
    assert np.allclose(got, np.asarray(axis) / np.linalg.norm(axis), atol=1e-3)
    assert r.endswith("t=[0.1, -0.25, 1.5] m)")


def test_pose_identity():
    assert short(Pose(np.eye(3), [0, 0, 2])) == "Pose(rotation 0 deg, t=[0, 0, 2] m)"


# --- rom ----------------------------------------------------------------------------------------------

def test_separated_model():
    F = np.ones((4, 90))
    grids = [np.linspace(0.0, 1.5, 7), np.linspace(10.0, 200.0, 5), np.linspace(0.2, 0.4, 3)]
    G = [np.ones((4, g.size)) for g in grids]
    r = short(SeparatedModel(F, grids, G, ["s", "P", "nu"], ["m", "N", ""], {"method": "pgd"}))
    assert r == "SeparatedModel(4 modes, 90 dofs, s in [0, 1.5] m, P in [10, 200] N, nu in [0.2, 0.4], method pgd)"


def test_rom_problem_parts():
    path = np.array([[0.0, 0, 0], [3.0, 4, 0], [3.0, 4, 2]])  # lengths 5 + 2
    r = short(MovingLoad(path, np.array([0.0, 0, -10]), 0.04))
    assert "path of 3 points" in r and number(r, rf"{NUM} m long") == 7.0 and "load [0, 0, -10] N" in r
    r = short(Translation(np.arange(17), np.array([0.0, 0, 1])))
    assert r == "Translation(17 nodes, direction [0, 0, 1])"
    r = short(Rotation(np.arange(5), np.array([0.0, 1, 0]), np.array([1.0, 0, 0])))
    assert r == "Rotation(5 nodes, axis [0, 1, 0] through [1, 0, 0] m, angle in deg)"
    mask = np.zeros(20, bool)
    mask[[1, 4, 6, 9, 11, 12, 19]] = True
    assert short(Modulus(mask, 2e9)) == "Modulus(7 of 20 cells, E_ref 2e+09 Pa)"
    space = FESpace(box_mesh((1.0, 1.0, 1.0), (2, 1, 1)), "P1")
    model = ElasticModel(space, LinearElastic(1e6, 0.3))
    pp = ParametricProblem(model, np.arange(12), ("load_position", "load_magnitude"), (None, None),
                           np.zeros(space.n_dofs), np.zeros(space.n_dofs), steps=4)
    r = short(pp)
    assert "12 fixed dofs" in r and "parameters load_position, load_magnitude" in r and "4 load steps" in r
    term = SeparatedTerm(sp.identity(36, format="csr"), (0,), {1: np.ones(3)})
    assert short(term) == "SeparatedTerm(sparse 36x36, axes (0,), factors on [1])"
    assert short(SeparatedTerm(np.ones((36, 8)))) == "SeparatedTerm(dense 36x8, axes (), factors on [])"


def test_discretisation_check():
    k = np.ones(3)
    chk = DiscretisationCheck(["s"], np.zeros((3, 1)), 0.01 * k, k, np.array([0.02, 0.05, 0.03]), k, np.zeros((3, 3)),
                              np.full(3, np.nan), k, np.zeros((3, 3)), k, k, 0.1, 2, 300, 2000, 1.5)
    r = short(chk)
    assert "refine 2, 3 points, 300 -> 2000 dofs" in r
    assert "displacement_l2 1 %" in r and "stress_l2 5 %" in r and "away_l2 n/a" in r


# --- integrators --------------------------------------------------------------------------------------

def test_dynamics_objects():
    m = box_mesh((1.0, 0.1, 0.1), (4, 1, 1))
    elastic = ElasticModel(FESpace(m, "P1"), LinearElastic(1e6, 0.3), density=1000.0)
    fixed = np.arange(12)  # the 4 nodes of the x = 0 face
    model = SolidModel(elastic, fixed, rayleigh=(0.5, 0.01), gravity=(0, 0, -9.81), ground=Ground(-0.5))
    r = short(model)
    assert r.startswith("SolidModel(ElasticModel(P1 on ") and "12 fixed dofs" in r
    assert "rayleigh (0.5, 0.01)" in r and "gravity [0, 0, -9.81] m/s^2" in r and "ground z0=-0.5 m" in r
    q = np.zeros(elastic.n_dofs)
    q[7] = -0.25
    v = np.full(elastic.n_dofs, 0.5)
    r = short(State(q, v, t=0.125, newton_iterations=3))
    assert r == f"State(t=0.125 s, {elastic.n_dofs} dofs, max |q| 0.25 m, max |v| 0.5 m/s, 3 Newton iterations)"
    assert short(StepStats([2, 3, 4], 2, 0)) == "StepStats(3 steps, 9 Newton iterations, 2 factorizations, " \
                                                "0 CG iterations)"
    assert short(make_integrator("be")) == "BackwardEuler()"
    traj = Trajectory([0.0, 0.1, 0.2], [q] * 3, [v] * 3, [{}] * 20)
    assert short(traj) == "Trajectory(3 frames, t 0..0.2 s, 20 energy records)"
    lin = Linearization(q, sp.identity(5, format="csr"), None, 2.0, 1e-9)
    assert short(lin) == f"Linearization({elastic.n_dofs} dofs, K 5x5 (5 non-zeros), D none, scale 2 N, floor 1e-09 N)"
    r = short(LinearDynamics(np.eye(3), 2 * np.eye(3), fixed=[0]))
    assert r == "LinearDynamics(3 dofs, 2 free, M 3 non-zeros, K 3 non-zeros, D none)"


# --- mpm ----------------------------------------------------------------------------------------------

def test_mpm_objects():
    torch = pytest.importorskip("torch")
    from physar.mpm import Control, MPMState, Params, build_model, parse_scene
    from physar.mpm.colliders import Collider
    from physar.mpm.identify import IdentifyResult
    from physar.mpm.runner import RunResult

    rho, lo, hi = 1000.0, np.array([0.375, 0.4375, 0.4]), np.array([0.625, 0.5625, 0.525])
    sc = parse_scene({"grid": {"size": 1.0, "resolution": 16},
                      "time": {"frame_dt": 2.5e-3, "substeps": 10, "frames": 1},
                      "boundary": {"ground": "slip", "walls": "none"},
                      "body": [{"shape": "box", "min": lo.tolist(), "max": hi.tolist(), "particles_per_cell": 8,
                                "E": 5e4, "nu": 0.3, "density": rho}]})
    model, x, v = build_model(sc)
    r = short(model)
    cells = np.prod(np.round((hi - lo) * 16))  # 4 x 2 x 2 grid cells, 8 particles each
    assert number(r, rf"{NUM} particles in 1 body") == 8 * cells == 128
    assert number(r, rf"mass {NUM} kg") == pytest.approx(rho * np.prod(hi - lo), rel=1e-3)
    assert "E 5e+04 Pa, nu 0.3" in r and "grid 16^3 cells of 0.0625 m" in r and "10 substeps" in r

    xs = np.zeros((128, 3))
    xs[:, 0] = np.linspace(0.1, 0.3, 128)
    xs[5] = (0.2, 0.7, 0.9)
    vs = np.zeros((128, 3))
    vs[3] = (0.0, 3.0, 4.0)
    r = short(MPMState.from_numpy(xs, vs, np.zeros((128, 3, 3)), np.tile(np.eye(3), (128, 1, 1)), np.ones(128)))
    assert r == "MPMState(128 particles on cpu, bounds [0.1, 0.3] x [0, 0.7] x [0, 0.9] m, max |v| 5 m/s)"

    omega = np.zeros(128)
    omega[:10] = 0.5
    r = short(Control(omega, x, v, kp=100.0))
    assert r.startswith("Control(128 particles, 10 actuated, omega 0..0.5, kp=100 1/s^2")

    E = torch.linspace(1e4, 5e4, 128, dtype=torch.float64).requires_grad_()
    r = short(Params(E, torch.full((128,), 0.3, dtype=torch.float64), l_e=torch.zeros(128, 8)))
    assert r.startswith("Params(128 particles, E 1e+04..5e+04 Pa, nu 0.3, l_e (128, 8)") and r.endswith("grad E)")

    r = short(Collider("capsule", radius=0.1, half_length=0.2, path=np.array([[0, 0, 0, 0], [1.5, 1, 1, 1.0]])))
    assert "path of 2 keyframes, t 0..1.5 s" in r and "radius 0.1 m" in r
    assert short(RunResult(3, [0.0, 0.1, 0.2], [{}] * 3, 128)) == "RunResult(3 frames, t 0..0.2 s, 128 particles)"
    r = short(IdentifyResult(np.array([5e4, 2e4]), np.array([0.3, 0.25]), 1e-6, [1.0] * 7))
    assert r == "IdentifyResult(E [5e+04, 2e+04] Pa, nu [0.3, 0.25], loss 1e-06, 7 iterations)"


# --- the package namespace ----------------------------------------------------------------------------

def test_dir_physar_has_no_import_leftovers():
    import importlib.metadata

    import physar

    assert not {"os", "sys", "version", "PackageNotFoundError"} & set(dir(physar))
    assert physar.__version__ == importlib.metadata.version("physar")


@pytest.mark.parametrize("preset, want", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_omp_wait_policy_still_set(preset, want):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if preset:
        env["OMP_WAIT_POLICY"] = preset
    out = subprocess.run([sys.executable, "-c", "import os, physar; print(os.environ['OMP_WAIT_POLICY'])"],
                         env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == want
