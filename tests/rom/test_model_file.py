"""Reduced-model files: round trip, format version and mesh checksum errors, no pickle."""
import numpy as np
import pytest

from physar.errors import PhysarError
from physar.fem import FESpace
from physar.geometry import box_mesh
from physar.rom import FORMAT_VERSION, ReducedModelError, SeparatedModel


def _model(n_dof):
    x = np.linspace(0, 1, 11)
    rng = np.random.default_rng(0)
    return SeparatedModel(rng.normal(size=(3, n_dof)), [x], [np.array([x, x**2, np.sin(x)])], ["s"], ["m"],
                          {"kind": "load_position", "path": [[0, 0, 0], [1, 0, 0]], "radius": 0.04})


def test_roundtrip_with_space(tmp_path):
    space = FESpace(box_mesh((1.0, 0.1, 0.1), (4, 1, 1)), "P1")
    m = _model(space.n_dofs)
    p = tmp_path / "m.npz"
    m.save(p, space=space)
    m2 = SeparatedModel.load(p, mesh=space.mesh)
    np.testing.assert_array_equal(m2.evaluate([0.37]), m.evaluate([0.37]))
    assert m2.metadata["path"] == [[0, 0, 0], [1, 0, 0]] and m2.metadata["radius"] == 0.04
    assert m2.metadata["element"] == "P1"
    assert m2.space().n_dofs == space.n_dofs
    np.testing.assert_array_equal(m2.mesh().points, space.mesh.points)
    assert [f.name for f in tmp_path.iterdir()] == ["m.npz"]  # no temporary left behind


def test_other_format_version(tmp_path):
    m = _model(12)
    p = tmp_path / "m.npz"
    m.save(p)
    z = dict(np.load(p))
    z["format_version"] = np.array(FORMAT_VERSION + 1)
    np.savez(tmp_path / "v2.npz", **z)
    with pytest.raises(ReducedModelError, match=rf"v2.npz: reduced-model format version {FORMAT_VERSION + 1}, "
                                                rf"this physar reads version {FORMAT_VERSION}"):
        SeparatedModel.load(tmp_path / "v2.npz")


def test_mismatched_mesh(tmp_path):
    space = FESpace(box_mesh((1.0, 0.1, 0.1), (4, 1, 1)), "P1")
    other = box_mesh((1.0, 0.1, 0.1), (5, 1, 1))
    moved = box_mesh((1.0, 0.1, 0.2), (4, 1, 1))  # same topology, other coordinates
    m = _model(space.n_dofs)
    p = tmp_path / "m.npz"
    m.save(p, mesh=space.mesh)
    SeparatedModel.load(p, mesh=space.mesh)
    for mesh in (other, moved):
        with pytest.raises(ReducedModelError, match="built on another mesh.*rebuild the model"):
            SeparatedModel.load(p, mesh=mesh)
    with pytest.raises(PhysarError, match="stores no mesh"):
        SeparatedModel.load(p).space()


def test_not_a_model(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros(3))
    (tmp_path / "t.npz").write_text("hello")
    np.savez(tmp_path / "o.npz", format_version=np.array(FORMAT_VERSION), names=np.array(["s"]),
             meta_keys=np.array([], dtype=str), meta_values=np.array([], dtype=str),
             F=np.array([{"a": 1}], dtype=object))
    np.savez(tmp_path / "x.npz", F=np.zeros((2, 3)))
    with pytest.raises(ReducedModelError, match="not a physar reduced model"):
        SeparatedModel.load(tmp_path / "a.npy")
    with pytest.raises(ReducedModelError, match="cannot read"):
        SeparatedModel.load(tmp_path / "t.npz")
    with pytest.raises(ReducedModelError, match="o.npz: cannot read.*allow_pickle"):  # needs pickle: refused
        SeparatedModel.load(tmp_path / "o.npz")
    with pytest.raises(ReducedModelError, match="no format_version"):
        SeparatedModel.load(tmp_path / "x.npz")
    with pytest.raises(ReducedModelError, match="cannot read"):
        SeparatedModel.load(tmp_path / "missing.npz")
