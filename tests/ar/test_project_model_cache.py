"""The AR project's cached model (``[model] file``) is rebuilt when rom.toml or the mesh file it names
changes (issue 16: a changed bracket.stl reused the old model.npz)."""

import types

import pytest

from physar.ar.project import _config_hash, load_model
from physar.errors import ConfigError
from physar.geometry import box_mesh, write_mesh

ROM = """
[mesh]
file = "plate.stl"
size = 0.04
[material]
model = "linear"
E = 1e7
nu = 0.3
[[fix]]
plane = { point = [0, 0, 0], normal = [1, 0, 0] }
[[parameter]]
name = "s"
kind = "load_position"
path = [[0.2, 0.05, 0.1], [0.4, 0.05, 0.1]]
points = 5
load = [0, 0, -1.0]
radius = 0.06
[rom]
method = "pgd"
max_modes = 3
"""


def _write_stl(d, length):
    write_mesh(d / "plate.stl", box_mesh((length, 0.1, 0.1), (4, 1, 1)).boundary().mesh)


def _cfg(d):
    return types.SimpleNamespace(_base_dir=d, model=types.SimpleNamespace(file="model.npz", config="rom.toml"))


def test_config_hash_follows_the_mesh_file(tmp_path):
    """The hash changes with the STL's content (not only rom.toml's bytes) and not when the same STL is
    written again. Catches: a hash of rom.toml alone (the issue-16 bug), a hash of the mtime."""
    (tmp_path / "rom.toml").write_text(ROM)
    _write_stl(tmp_path, 0.5)
    h0 = _config_hash(tmp_path / "rom.toml")
    _write_stl(tmp_path, 0.5)
    assert _config_hash(tmp_path / "rom.toml") == h0
    _write_stl(tmp_path, 0.6)
    assert _config_hash(tmp_path / "rom.toml") != h0


def test_changed_stl_rebuilds_the_model_and_an_unchanged_one_does_not(tmp_path):
    """load_model writes model.npz; an unchanged STL reuses it (same bytes, no rebuild), a changed STL
    rebuilds it (new bytes, the new mesh's extent), and with build=False refuses naming both files.
    Catches: a hash of rom.toml alone (the old model of the 0.5 m plate would be reused)."""
    (tmp_path / "rom.toml").write_text(ROM)
    _write_stl(tmp_path, 0.5)
    cfg = _cfg(tmp_path)
    rom = load_model(cfg, "project.toml")
    npz = tmp_path / "model.npz"
    first = npz.read_bytes()
    assert rom.metadata["config_sha256"] == _config_hash(tmp_path / "rom.toml")
    load_model(cfg, "project.toml")
    assert npz.read_bytes() == first  # reused, not rebuilt
    _write_stl(tmp_path, 0.6)
    with pytest.raises(ConfigError, match=r"was not built from 'rom.toml' and plate.stl as they are now"):
        load_model(cfg, "project.toml", build=False)
    rom2 = load_model(cfg, "project.toml")
    assert npz.read_bytes() != first
    pts, _ = rom2._mesh_arrays
    assert pts[:, 0].max() == pytest.approx(0.6, abs=1e-6)
