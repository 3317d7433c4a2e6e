"""Meshes in several pieces, nodes in no element, and the up-front memory estimate of a solve.

`check_constraints` tests each connected piece of the mesh (elements sharing a node) against its own fixed
dofs: a second body left free, a crack whose faces were not merged, or a "tet soup" of unmerged duplicate nodes
is refused in one line (it used to pass: the direct solver returned a 6e7 m displacement, AMG/CG ran on).
The references are built by construction: node and element counts of the pieces, the number of nodes
duplicated along a crack plane, and the solution of each piece solved alone.
"""

import tracemalloc

import numpy as np
import pytest
from typer.testing import CliRunner

import physar.output
from physar.errors import ConfigError, SolverError
from physar.fem import ElasticModel, FESpace, check_constraints, solve_static
from physar.fem.materials import LinearElastic
from physar.fem.solvers import LinearSolver, estimate_nnz, estimate_solve_memory
from physar.geometry import box_mesh
from physar.geometry.mesh import TetMesh

MAT = LinearElastic(1e9, 0.3)


def _x0(space, x=0.0):
    """All dofs of the nodes on the plane X = x."""
    return np.flatnonzero(np.repeat(np.abs(space.nodes[:, 0] - x) < 1e-9, 3))


def _two_cubes():
    """A unit cube of 2 x 2 x 2 cells (27 nodes, 48 tets) and, apart at x in [2, 3], one of 1 cell (8, 6)."""
    a, b = box_mesh((1, 1, 1), (2, 2, 2)), box_mesh((1, 1, 1), (1, 1, 1))
    mesh = TetMesh(np.vstack([a.points, b.points + [2.0, 0, 0]]), np.vstack([a.cells, b.cells + a.n_points]))
    return a, b, mesh


def _tip_load(space, x, total=-1e3):
    f = np.zeros(space.n_dofs)
    tip = np.flatnonzero(np.abs(space.nodes[:, 0] - x) < 1e-9)
    f[3 * tip + 2] = total / len(tip)
    return f


def test_a_second_body_left_free_is_named_with_its_size():
    # mutants: only the largest piece checked (the whole mesh's 6 modes: the free small cube passes); cells not
    # passed by solve_static (same); the smaller piece's element / node counts or box mixed up with the largest's
    _, _, mesh = _two_cubes()
    space = FESpace(mesh, "P1")
    with pytest.raises(SolverError) as e:
        solve_static(ElasticModel(space, MAT), _tip_load(space, 1.0), _x0(space))
    msg = str(e.value)
    assert "\n" not in msg
    assert "2 separate pieces" in msg and "1 of them is not fully constrained" in msg
    assert "6 elements and 8 nodes" in msg and "[2.0, 0.0, 0.0]-[3.0, 1.0, 1.0]" in msg
    assert "all 6 rigid-body modes free" in msg and "no node of it coincides" in msg
    # the same with P2 nodes (8 vertices + 19 edge nodes), and through LinearSolver
    space2 = FESpace(mesh, "P2")
    with pytest.raises(SolverError, match="6 elements and 27 nodes"):
        LinearSolver(ElasticModel(space2, MAT), _x0(space2))


def test_each_piece_held_by_its_own_supports_solves_as_the_pieces_alone():
    # mutant: every fixed dof counted for the first piece (the second piece's supports ignored): refused here
    a, b, mesh = _two_cubes()
    for element in ("P1", "P2"):
        space = FESpace(mesh, element)
        fixed = np.union1d(_x0(space, 0.0), _x0(space, 2.0))
        check_constraints(space.nodes, fixed, space.cells)
        f = _tip_load(space, 1.0) + _tip_load(space, 3.0, total=-2e3)
        u = solve_static(ElasticModel(space, MAT), f, fixed).u.reshape(-1, 3)
        # reference: each cube solved alone
        for piece, shift, total in ((a, 0.0, -1e3), (b, 2.0, -2e3)):
            s = FESpace(piece, element)
            ref = solve_static(ElasticModel(s, MAT), _tip_load(s, 1.0, total), _x0(s)).u.reshape(-1, 3)
            near = np.linalg.norm(space.nodes[:, None] - (s.nodes + [shift, 0, 0])[None], axis=2)
            idx = near.argmin(0)
            assert np.allclose(near.min(0), 0.0) and np.allclose(u[idx], ref, rtol=1e-8, atol=1e-12)


def _cracked_box(scale=1.0, jitter=0.0):
    """A 4 x 3 x 2 cell box [0, 1] x [0, 1] x [0, 1] (x `scale`) whose elements right of x = 0.5 get their own
    copies of the 4 x 3 = 12 nodes on that plane (an unmerged crack across the whole section); the copies moved
    by `jitter` x the size. Returns (mesh, number of duplicated nodes)."""
    m = box_mesh((scale, scale, scale), (4, 3, 2))
    P, C = m.points.copy(), m.cells.copy()
    plane = np.flatnonzero(np.abs(P[:, 0] - 0.5 * scale) < 1e-9 * scale)
    new = np.arange(len(P))
    new[plane] = len(P) + np.arange(len(plane))
    right = P[C].mean(1)[:, 0] > 0.5 * scale
    C[right] = new[C[right]]
    copies = P[plane] + jitter * scale * np.array([0.3, -0.5, 0.7])
    return TetMesh(np.vstack([P, copies]), C), len(plane)


@pytest.mark.parametrize("scale, jitter", [(1.0, 0.0), (1e3, 1e-10)])
def test_an_unmerged_crack_counts_the_coincident_nodes(scale, jitter):
    # mutants: the coincidence tolerance absolute (1e-9 m: the jittered copies on the 1 km box are missed), the
    # piece's own nodes counted (every node coincides with itself: 36), the count of the fixed piece
    mesh, n_dup = _cracked_box(scale, jitter)
    assert n_dup == 12
    space = FESpace(mesh, "P1")
    with pytest.raises(SolverError) as e:
        check_constraints(space.nodes, _x0(space), space.cells)
    msg = str(e.value)
    assert f"{n_dup} of its nodes coincide with nodes of another piece" in msg and "merge coincident nodes" in msg
    # the free right half: 2 x 3 x 2 cells of 6 tets, (2 + 1) x (3 + 1) x (2 + 1) nodes
    assert "72 elements and 36 nodes" in msg


def test_a_tet_soup_is_refused_before_any_iteration():
    # every tetrahedron its own piece (each one's nodes duplicated); fixed at x = 0: a tet is held only when a
    # whole face lies on x = 0 (3 non-collinear nodes); the others are free. Used to run AMG/CG without end.
    # mutant: the per-piece test of the fixed dofs dropped (pieces with some fixed dofs counted as held)
    m = box_mesh((1, 1, 1), (2, 2, 2))
    pts = m.points[m.cells].reshape(-1, 3)
    soup = TetMesh(pts, np.arange(len(pts)).reshape(-1, 4))
    space = FESpace(soup, "P1")
    on_face = (np.abs(m.points[m.cells][:, :, 0]) < 1e-9).sum(1) >= 3
    n_free = int(len(m.cells) - on_face.sum())
    with pytest.raises(SolverError) as e:
        solve_static(ElasticModel(space, MAT), _tip_load(space, 1.0), _x0(space), linear="amg")
    msg = str(e.value)
    assert f"{len(m.cells)} separate pieces" in msg and f"{n_free} of them are not fully constrained" in msg
    assert "1 element and 4 nodes" in msg and "4 of its nodes coincide" in msg


def test_one_piece_keeps_the_rigid_body_mode_messages():
    space = FESpace(box_mesh((1, 0.1, 0.1), (4, 1, 1)), "P1")
    check_constraints(space.nodes, _x0(space), space.cells)
    with pytest.raises(SolverError, match="not constrained: all 6 rigid-body modes are free"):
        check_constraints(space.nodes, [], space.cells)
    # u_z = 0 on the face x = 0 only: it holds the rotation about x and one mix of the z translation with the
    # rotation about y (the face turning about its own line); x, y translations, z rotation and that mix are free
    z = _x0(space)[2::3]
    with pytest.raises(SolverError, match=r"not fully constrained: 4 rigid-body mode\(s\) free .*translation x"):
        check_constraints(space.nodes, z, space.cells)


def test_a_node_in_no_element_is_refused_unless_fixed():
    # it has no stiffness: K has an empty row and the direct solver reported "exactly singular", AMG NaN
    # mutant: nodes in no element not looked for (the old behaviour)
    m = box_mesh((1, 1, 1), (2, 2, 2))
    mesh = TetMesh(np.vstack([m.points, [[5.0, 5.0, 5.0]]]), m.cells)
    space = FESpace(mesh, "P1")
    model = ElasticModel(space, MAT)
    f = _tip_load(space, 1.0)
    with pytest.raises(SolverError, match=r"1 node\(s\) belong to no element \(node 27 at \[5.0, 5.0, 5.0\]\)"):
        solve_static(model, f, _x0(space))
    # all its dofs fixed: it takes no part, and the body's solution is that of the mesh without it
    u = solve_static(model, f, np.union1d(_x0(space), [81, 82, 83])).u
    s = FESpace(m, "P1")
    ref = solve_static(ElasticModel(s, MAT), _tip_load(s, 1.0), _x0(s)).u
    assert np.allclose(u[:81], ref, rtol=1e-10, atol=1e-14) and np.all(u[81:] == 0)


def test_fem_solve_of_a_two_piece_mesh_file_exits_2_in_one_line(tmp_path):
    from physar.cli.main import app
    from physar.geometry import write_mesh

    _, _, mesh = _two_cubes()
    write_mesh(tmp_path / "two.vtu", mesh)
    cfg = tmp_path / "p.toml"
    cfg.write_text('[mesh]\nfile = "two.vtu"\n[material]\nmodel = "linear"\nE = 1e9\nnu = 0.3\n'
                   '[[fix]]\nbox = [[0, 0, 0], [0, 1, 1]]\n'
                   '[[load]]\ntype = "traction"\nbox = [[1, 0, 0], [1, 1, 1]]\ntotal = [0, 0, -1000]\n'
                   '[fem]\nelement = "P1"\n')
    out = tmp_path / "out.vtu"
    r = CliRunner().invoke(app, ["fem", "solve", str(cfg), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "6 elements and 8 nodes" in lines[0] and not out.exists()


# ------------------------------------------------------------------------------------------ memory estimate
@pytest.mark.parametrize("element, cells", [("P1", (12, 6, 3)), ("P2", (8, 4, 2)), ("P1", (30, 2, 2)),
                                            ("P2", (20, 2, 1))])
def test_nnz_estimate_is_within_25_percent_of_the_assembled_matrix(element, cells):
    # mutants: the P1 count used for P2 (nnz 4x low), the P2 face pairs dropped, the 9 (3 x 3 dofs) dropped
    space = FESpace(box_mesh((2, 1, 0.5), cells), element)
    K = ElasticModel(space, MAT).tangent_stiffness()
    est = estimate_nnz(element, space.mesh.n_points, space.n_nodes, len(space.cells))
    assert 0.75 * K.nnz <= est <= 1.1 * K.nnz  # boundary edges and faces left out: low on thin meshes


def test_assembly_estimate_is_within_a_factor_2_of_the_measured_peak():
    # mutant: bytes per element-matrix entry 10x off (or the element matrices counted per element, not entry)
    space = FESpace(box_mesh((2, 1, 0.5), (8, 4, 2)), "P2")
    model = ElasticModel(space, MAT)
    _ = model._quad  # geometry (not part of the assembly estimate)
    tracemalloc.start()
    try:
        model.tangent_stiffness()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    est = estimate_solve_memory(space, space.n_dofs, "direct")["assembly"]
    assert 0.5 * peak <= est <= 2.0 * peak


def test_a_solve_needing_more_memory_than_available_is_refused_before_assembly(monkeypatch):
    # mutants: the check not called by solve_static / LinearSolver, or its comparison reversed (the small
    # problem then refused with the real memory)
    space = FESpace(box_mesh((1, 0.1, 0.1), (8, 1, 1)), "P2")
    model = ElasticModel(space, MAT)
    fixed, f = _x0(space), _tip_load(space, 1.0)
    solve_static(model, f, fixed)  # fits in the real memory
    model = ElasticModel(space, MAT)
    monkeypatch.setattr(physar.output, "available_memory", lambda: 2**16)
    calls = []
    monkeypatch.setattr(model, "tangent_stiffness", lambda *a: calls.append(a))
    for solve in (lambda: solve_static(model, f, fixed, linear="direct"), lambda: LinearSolver(model, fixed)):
        with pytest.raises(ConfigError) as e:
            solve()
        msg = str(e.value)
        assert "\n" not in msg and f"{len(f) - len(fixed):,} free dofs" in msg and "64 KiB" not in msg
        assert "more than the 0.0625 MiB available" in msg
        assert "coarser mesh" in msg and "P1 elements" in msg and 'linear = "amg"' in msg
    assert calls == []


def test_fem_solve_refused_for_memory_exits_2_in_one_line(tmp_path, monkeypatch):
    # mutant: the refusal raised as a plain exception (a traceback, exit 1)
    from pathlib import Path

    from physar.cli.main import app

    example = Path(__file__).resolve().parents[2] / "examples" / "cantilever.toml"
    monkeypatch.setattr(physar.output, "available_memory", lambda: 2**20)
    out = tmp_path / "out.vtu"
    r = CliRunner().invoke(app, ["fem", "solve", str(example), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "of memory with the direct solver" in lines[0] and "1 MiB available" in lines[0]
    assert not out.exists()
