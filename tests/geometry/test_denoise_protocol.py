"""The default denoiser (`two-stage`) on a sharp CAD-like mesh under the literature's protocol (issue 20).

Everything the verdict rests on is computed here, independently of physar: the noise (random unit direction
per vertex, std 0.3 ē), the mean face-normal angle error against the clean copy, the enclosed volume, and
the peer, a uniform-umbrella Taubin λ|μ smoother (λ = 0.5, μ = -0.53, Taubin 1995) written in this file and
tuned on the clean mesh (best iteration count), which physar's default must beat without seeing the clean
mesh.
"""

import json

import numpy as np
import pytest
import trimesh
from scipy import sparse
from typer.testing import CliRunner

from physar.cli.main import app
from physar.geometry import denoise as D
from physar.geometry.io import write_mesh
from physar.geometry.mesh import TriMesh
from physar.geometry.tetra import plate_with_hole_surface


def cad_mesh() -> TriMesh:
    """Plate with a through hole (sharp 90° edges, a cylindrical face), outward wound (trimesh)."""
    m = plate_with_hole_surface(0.2, 0.1, 0.03, 0.025, 0.008)
    t = trimesh.Trimesh(m.points, m.faces, process=False)
    trimesh.repair.fix_normals(t)
    return TriMesh(np.asarray(t.vertices), np.asarray(t.faces), name="plate")


def edges_of(faces: np.ndarray) -> np.ndarray:
    return np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)


def add_noise(points: np.ndarray, faces: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    """Literature protocol, written here: d_i = sigma ē N(0,1) u_i, u_i uniform on the unit sphere."""
    e = edges_of(faces)
    ebar = np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1).mean()
    rng = np.random.default_rng(seed)
    u = rng.normal(size=points.shape)
    u /= np.linalg.norm(u, axis=1)[:, None]
    return points + sigma * ebar * rng.normal(size=(len(points), 1)) * u


def normal_error(p: np.ndarray, ref: np.ndarray, faces: np.ndarray) -> float:
    """Mean angle (degrees) between face normals of two embeddings of the same faces."""
    def fn(x):
        c = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
        return c / np.linalg.norm(c, axis=1)[:, None]
    return float(np.degrees(np.arccos(np.clip((fn(p) * fn(ref)).sum(axis=1), -1, 1))).mean())


def volume(p: np.ndarray, faces: np.ndarray) -> float:
    x = p[faces]
    return float(np.einsum("ij,ij->i", x[:, 0], np.cross(x[:, 1], x[:, 2])).sum() / 6)


def taubin_best(noisy: np.ndarray, clean: np.ndarray, faces: np.ndarray) -> float:
    """Independent Taubin smoother at its best iteration count (oracle: needs the clean mesh)."""
    e = edges_of(faces)
    n = len(noisy)
    a = sparse.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), (n, n)).tocsr()
    w = sparse.diags(1.0 / np.asarray(a.sum(axis=1)).ravel()) @ a
    q, best = noisy.copy(), np.inf
    for _ in range(100):
        q = q + 0.5 * (w @ q - q)
        q = q - 0.53 * (w @ q - q)
        best = min(best, normal_error(q, clean, faces))
    return best


@pytest.fixture(scope="module")
def case():
    clean = cad_mesh()
    noisy = add_noise(clean.points, clean.faces, 0.3, seed=7)
    return clean, noisy


def test_default_beats_tuned_taubin_on_sharp_cad(case):
    """At 0.3 ē, the automatic default's normal error is below 0.3 of a tuned Taubin's (measured 1.6° vs
    9.4°, 1157 vertices; SURE picks σ_r 0.35, 50 iterations) and the volume stays within 1 %. Mutants caught
    (error 3.6-5.1°): no vertex update (stage 3 returns its input: 4.8°), a rule that never filters past one
    iteration (3.6°), stage 1 skipped (filter_normals returns its input: 5.1°), SURE without its divergence
    term (it then keeps the least filtered result: 3.8°). Not caught: unweighted Taubin in stage 2 (the
    re-filter and vertex update restore the edges on this part, measured before SURE: 1.6°)."""
    clean, noisy = case
    out = D.denoise(clean.with_points(noisy))  # the CLI's default method, no parameters
    err = normal_error(out.points, clean.points, clean.faces)
    ref = taubin_best(noisy, clean.points, clean.faces)
    assert normal_error(noisy, clean.points, clean.faces) > 15  # the noise is there
    assert err < 0.3 * ref, (err, ref)
    dv = volume(out.points, clean.faces) / volume(clean.points, clean.faces) - 1
    assert abs(dv) < 0.01


def test_denoise_cli_reference_and_picture(tmp_path, case):
    """`physar denoise --reference --json` reports the errors this file computes independently, and the PNG
    is a real picture. Mutants caught: before/after swapped in the report, distance in metres reported as
    edge lengths, no picture written."""
    clean, noisy = case
    src, ref, out, png = tmp_path / "noisy.ply", tmp_path / "clean.ply", tmp_path / "out.ply", tmp_path / "ba.png"
    write_mesh(src, clean.with_points(noisy))
    write_mesh(ref, clean)
    r = CliRunner().invoke(app, ["denoise", str(src), str(out), "--reference", str(ref), "--render", str(png),
                                 "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)["reference"]
    from physar.geometry.io import read_mesh

    res = read_mesh(out, kind="tri")
    assert rep["normal_error_deg"] == pytest.approx(normal_error(res.points, clean.points, clean.faces), rel=1e-6)
    assert rep["normal_error_deg_before"] == pytest.approx(normal_error(noisy, clean.points, clean.faces), rel=1e-4)
    e = edges_of(clean.faces)
    ebar = np.linalg.norm(clean.points[e[:, 0]] - clean.points[e[:, 1]], axis=1).mean()
    assert rep["mean_distance_edge"] == pytest.approx(rep["mean_distance_m"] / ebar, rel=1e-9)
    assert rep["mean_distance_m"] < rep["mean_distance_m_before"]
    assert rep["volume_change"] == pytest.approx(volume(res.points, clean.faces) / volume(clean.points, clean.faces)
                                                 - 1, abs=1e-6)
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    # a parameter the method does not take is one line, exit 2, nothing written
    bad = tmp_path / "bad.ply"
    r = CliRunner().invoke(app, ["denoise", str(src), str(bad), "--method", "taubin", "--xi", "0.5"])
    assert r.exit_code == 2 and "--xi does not apply" in r.output and not bad.exists()
