"""Denoising a mesh that has no noise, and inputs that have no surface (issue: `physar denoise` on a clean box
crashed with ZeroDivisionError in normal_filter.sure_tilt; a clean 4 x 1 x 1 box moved by 7 % of its side).

References written here: the input's own points (a noise-free mesh must come back as it was), the box's
volume 1 x 0.1 x 0.1 m³ by the divergence theorem, face normals by cross products, files written as text.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import typer
from typer.testing import CliRunner

from physar.cli.denoise import register
from physar.geometry import denoise as D
from physar.geometry import normal_filter as NF
from physar.geometry.mesh import TriMesh, boundary_surface, box_mesh


def box(cells):
    """Boundary surface of the tetrahedral 1 x 0.1 x 0.1 m box (what `physar mesh box` writes)."""
    return boundary_surface(box_mesh((1.0, 0.1, 0.1), cells)).mesh


def volume(points, faces):
    """Enclosed volume, sum of x0 . (x1 x x2) / 6 over outward faces."""
    x = points[faces]
    return float(np.einsum("ij,ij->i", x[:, 0], np.cross(x[:, 1], x[:, 2])).sum()) / 6.0


def mean_normal_angle(points, ref, faces):
    """Mean angle (degrees) between the face normals of two meshes with the same faces."""
    def unit(p):
        c = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
        return c / np.linalg.norm(c, axis=1)[:, None]
    return float(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", unit(points), unit(ref)), -1, 1))).mean())


@pytest.mark.parametrize("cells", [(20, 4, 4), (4, 1, 1)])
def test_noise_free_box_comes_back_unchanged(cells):
    """A clean box (20 x 4 x 4 cells: noise estimate exactly 0; 4 x 1 x 1: 3e-10 m, the quadric fit's round-off)
    comes back with its points unchanged and its volume 0.01 m³, and so does the coarse box with 1e-7 m of noise
    (no measurable noise on 0.2 m edges). Mutants caught: the σ = 0 shortcut removed (20 x 4 x 4:
    ZeroDivisionError in sure_tilt), the input not among the SURE candidates (4 x 1 x 1: stage 2 alone moved
    the vertices by 0.074 m on average and the volume by -7.8 %)."""
    clean = box(cells)
    for pts in (clean.points, clean.points + 1e-7 * np.random.default_rng(0).standard_normal(clean.points.shape)):
        info = {}
        out = NF.normal_filter_denoise(clean.with_points(pts), info=info)
        np.testing.assert_array_equal(out.points, pts)
        assert info["normal_iterations"] == 0
        assert volume(out.points, out.faces) == pytest.approx(0.01, rel=1e-5)
    out = D.denoise(clean)  # the default method, as the CLI runs it
    np.testing.assert_array_equal(out.points, clean.points)


def test_noisy_box_is_still_filtered():
    """The input is a candidate, not the answer: with noise of 0.1 mean edge lengths (random directions) the
    default still filters and lowers the mean face-normal error against the clean box at least 4-fold
    (measured 7.8 -> 1.05 degrees). Mutant caught: the input always returned (the comparison with its
    estimate reversed)."""
    clean = box((20, 4, 4))
    rng = np.random.default_rng(1)
    e = np.unique(np.sort(clean.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    ebar = np.linalg.norm(clean.points[e[:, 0]] - clean.points[e[:, 1]], axis=1).mean()
    u = rng.standard_normal(clean.points.shape)
    noisy = clean.points + 0.1 * ebar * rng.standard_normal((len(u), 1)) * u / np.linalg.norm(u, axis=1)[:, None]
    info = {}
    out = NF.normal_filter_denoise(clean.with_points(noisy), info=info)
    assert info["normal_iterations"] > 0
    before = mean_normal_angle(noisy, clean.points, clean.faces)
    assert mean_normal_angle(out.points, clean.points, clean.faces) < before / 4, before


def test_bnf_on_a_lone_triangle():
    """The bilateral-normal-filter baseline on one flat triangle returns it unchanged (its one face normal is
    already filtered). Mutant caught: the spatial width as the mean over an empty set of neighbour pairs
    (NaN positions, refused as "NaN or infinite coordinate")."""
    tri = TriMesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), name="tri")
    np.testing.assert_allclose(D.denoise(tri, "bnf").points, tri.points, atol=1e-12)


PLY_HEAD = "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"


def ply(path, pts, faces=()):
    text = PLY_HEAD.format(n=len(pts))
    if len(faces):
        text += f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
    text += "end_header\n" + "".join(" ".join(map(str, p)) + "\n" for p in pts)
    text += "".join("3 " + " ".join(map(str, f)) + "\n" for f in faces)
    path.write_text(text)
    return path


@pytest.fixture
def cli():
    app = typer.Typer()
    register(app)
    return lambda *args: CliRunner().invoke(app, [str(a) for a in args])


def test_cli_clean_inputs_are_written_unchanged(cli, tmp_path):
    """A one-triangle OFF and a one-triangle PLY (no noise to estimate: σ_e = 0) are denoised by the default
    into their own points, exit 0. Mutant caught: the σ = 0 shortcut removed (ZeroDivisionError, a
    traceback)."""
    off = tmp_path / "tri.off"
    off.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    tri = ply(tmp_path / "tri.ply", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    for src in (off, tri):
        out = tmp_path / f"d_{src.name}"
        r = cli("denoise", src, "-o", out, "--no-render")
        assert r.exit_code == 0, r.output
        got = trimesh.load(out, process=False)
        np.testing.assert_allclose(np.asarray(got.vertices), [[0, 0, 0], [1, 0, 0], [0, 1, 0]], atol=1e-7)
        assert "the input came back unchanged: no filtering is estimated to beat it" in r.output  # said, not silent


@pytest.mark.parametrize(("name", "pts", "faces", "words"), [
    ("zero.ply", [(0, 0, 0)] * 4, [(0, 1, 2), (0, 3, 1), (1, 3, 2), (2, 3, 0)], "all its points coincide"),
    ("line.ply", [(0, 0, 0), (1, 1, 1), (2, 2, 2)], [(0, 1, 2)], "the surface has zero area; there is no"),
    ("same.ply", [(1, 1, 1)] * 20, [], "all its points coincide"),
    ("rod.ply", [(t, 2 * t, 0.0) for t in np.linspace(0, 1, 30)], [], "lie on one line"),
])
def test_cli_refuses_inputs_without_a_surface(cli, tmp_path, name, pts, faces, words):
    """A mesh of zero area (4 coincident vertices; 3 collinear ones) and a point cloud of identical or collinear
    points have no normals to denoise along: exit 2, one line naming the file, no output written. Mutants
    caught: the surface area check removed (the coincident mesh is written back unchanged, exit 0, the
    collinear one too), the point-cloud check not called (both clouds written back, exit 0)."""
    src = ply(tmp_path / name, pts, faces)
    out = tmp_path / "out.ply"
    r = cli("denoise", src, "-o", out, "--no-render")
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and r.output.count("\n") == 1
    assert r.output.startswith(f"error: {src}") or r.output.startswith(f"error: {name}"), r.output
    assert words in r.output, r.output
    assert not out.exists()


def test_cli_never_overwrites_the_reference(cli, tmp_path):
    """`-o` naming the --reference file is refused like `-o` naming the input: exit 2, one line naming it, the
    reference byte for byte as it was. Mutant caught: --reference left out of the output's input check (the
    clean reference was overwritten by the denoised mesh)."""
    clean = box((4, 1, 1))
    ref = ply(tmp_path / "ref.ply", clean.points.tolist(), clean.faces.tolist())
    noisy = ply(tmp_path / "surf.ply", (clean.points + 1e-3).tolist(), clean.faces.tolist())
    before = ref.read_bytes()
    r = cli("denoise", noisy, "-o", ref, "--reference", ref, "--no-render")
    assert r.exit_code == 2, r.output
    assert "ref.ply" in r.output and "same file" in r.output and r.output.count("\n") == 1
    assert ref.read_bytes() == before
