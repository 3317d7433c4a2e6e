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


# ------------------------------------------------------------------------------------------------ corrupt arrays
# A model file whose arrays do not fit together (edited, truncated, NaN) is refused at load in one line naming
# the file and the array; before, `rom eval` died on a reshape, `assimilate` on a matmul, or printed NaN.
def _saved(tmp_path, **edit):
    """A P1 model on a 4x1x1 box saved with its mesh, then re-saved with the arrays in ``edit`` replaced."""
    space = FESpace(box_mesh((1.0, 0.1, 0.1), (4, 1, 1)), "P1")
    p = tmp_path / "m.npz"
    _model(space.n_dofs).save(p, space=space)
    z = dict(np.load(p))
    for k, f in edit.items():
        z[k] = f(z[k].copy())
    np.savez(p, **z)
    return p


def test_modes_that_do_not_match_the_stored_mesh_are_refused(tmp_path):
    # mutant: the load does not compare F's columns with the stored mesh's DOFs (then `rom eval` fails on a
    # reshape). Reference: a 4x1x1 box has 5*2*2 = 20 vertices, 60 P1 DOFs.
    p = _saved(tmp_path, F=lambda F: F[:, :50])
    with pytest.raises(ReducedModelError, match=r"m\.npz: F has 50 columns, the stored mesh \(20 points, P1\) "
                                                r"has 60 DOFs"):
        SeparatedModel.load(p)


def _put(a, value, index=(0, 0)):
    a = a.astype(float)
    a[index] = value
    return a


@pytest.mark.parametrize(("key", "value", "index"), [("F", np.nan, (0, 0)), ("F", np.inf, (2, 5)),
                                                     ("G_0", np.nan, (1, 3)), ("grid_0", -np.inf, (4,))])
def test_non_finite_arrays_are_refused(tmp_path, key, value, index):
    # mutant: no finiteness check at load (a NaN in F gave `rom eval` "max displacement nan m", exit 0)
    p = _saved(tmp_path, **{key: lambda a: _put(a, value, index)})
    where = ", ".join(map(str, index))
    with pytest.raises(ReducedModelError, match=rf"m\.npz: {key}\[{where}\] = -?{value} is not a finite number"):
        SeparatedModel.load(p)


@pytest.mark.parametrize(("edit", "message"), [
    ({"mesh_points": lambda a: _put(a, np.nan, (2, 1))}, r"m\.npz: mesh_points: point 2 is not a finite number"),
    ({"mesh_cells": lambda a: _put(a, 10**6).astype(np.int64)},
     r"m\.npz: stored mesh \(mesh_points, mesh_cells\): element 0 refers to a node outside 0\.\.19"),
    ({"mesh_cells": lambda a: a.astype(float)}, r"m\.npz: mesh_cells must be integer node indices"),
    ({"grid_0": lambda a: a[::-1]}, (r"m\.npz: grid_0 \(parameter 's'\) must be strictly increasing; "
                                    r"grid_0\[1\] = 0\.9 follows grid_0\[0\] = 1\.0")),
    ({"G_0": lambda a: a[:, :5]}, r"m\.npz: G_0 \(parameter 's'\) has shape \(3, 5\), expected \(3, 11\)"),
    ({"F": lambda a: a[0]}, r"m\.npz: F has shape \(60,\), expected \(n_modes, n_dof\)"),
    ({"units": lambda a: a[:0]}, r"m\.npz: units has 0 entries for 1 parameters"),
])
def test_errors_of_a_bad_model_name_the_file_and_the_array(tmp_path, edit, message):
    # mutant: the mesh checked under the name "mesh" and the grid by the constructor ("mesh: point 0 ...",
    # "SeparatedModel: grid ..."), neither naming the .npz; or a shape left unchecked
    p = _saved(tmp_path, **edit)
    with pytest.raises(ReducedModelError, match=message):
        SeparatedModel.load(p)
